"""A copy of an arm's SQLite database whose chosen classifier's rows carry the method keys of another arm.

    python -m experiments.substance_draw.keys ARM.db OUT.db --keep 3 --as 2

`experiments.bn_adaptation.compare` pairs two arms method key by method key; an arm that retrained
the classifier holds its rows under the new classifier's id (`classifier:3`, `fit:3`). This copies the
database (SQLite backup API), drops every other classifier's `classifier:*` and `fit:*` rows, and
renames the kept ones (`classifier:3` -> `classifier:2`). `--method FROM --as TO` instead gives one
method's rows another method's key, which pairs two methods of the same run.
"""

from __future__ import annotations

import argparse
import sqlite3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source")
    parser.add_argument("target")
    parser.add_argument("--keep", help="the classifier id whose ours/fit rows are kept")
    parser.add_argument("--method", help="a method key whose rows are renamed (instead of --keep)")
    parser.add_argument("--as", dest="as_", required=True, help="classifier id (with --keep) or method key")
    args = parser.parse_args()
    source, target = sqlite3.connect(args.source), sqlite3.connect(args.target)
    source.backup(target)
    source.close()
    if args.method:
        renames = [(args.method, args.as_)]
    else:
        renames = [(f"{prefix}:{args.keep}", f"{prefix}:{args.as_}") for prefix in ("classifier", "fit")]
        for prefix in ("classifier", "fit"):
            target.execute("DELETE FROM assignment WHERE method_key LIKE ? AND method_key != ?",
                           (f"{prefix}:%", f"{prefix}:{args.keep}"))
    for old, new in renames:
        if old == new:
            continue
        target.execute("DELETE FROM assignment WHERE method_key = ?", (new,))
        target.execute("UPDATE assignment SET method_key = ? WHERE method_key = ?", (new, old))
    target.commit()
    for key, count in target.execute("SELECT method_key, count(*) FROM assignment GROUP BY method_key"):
        print(key, count)


if __name__ == "__main__":
    main()
