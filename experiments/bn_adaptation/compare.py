"""Two runs of the same collection, paired: each method's figures in arm B minus arm A, over the same exemplars.

    python -m experiments.bn_adaptation.compare --a sqlite:////work/A.db --b sqlite:////work/B.db \\
        --groundtruth /work/second-world/groundtruth.json --source second-world

`photoshape eval` pairs every method against ours inside one run; an experiment that changes a
network's input (here: its BatchNorm prior) needs the same method compared across two runs of the
same rows (a copy of the database before the change, the database after it; one blob store). For
each method key in both, and each of top-1, top-5 and substance accuracy: A, B and B - A with a
95% bootstrap interval that resamples the same exemplars for both arms
(`evaluation.bootstrap.difference_interval`). A method ranked by several classifiers in one arm
(a copy whose classifier was trained again keeps the old one's rows) is read at its newest
classifier: `fit` of A's newest pairs with `fit` of B's. The substances stage's own part labels
(`substances`) are paired too, so two arms that differ only in that stage compare before any
network downstream of it is trained. Read-only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.bootstrap import difference_interval, mean_interval
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.method_keys import classifier_id_of, method_of
from photoshape_flow.scoring.evaluate import inference_observations, part_substance_hits
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore

METRICS = ("material_top1", "material_top5", "substance_accuracy")


def observations(url: str, groundtruth: Path, source: str, store: BlobStore) -> dict:
    gt = read_groundtruth_file(groundtruth)
    with session_scope(url) as session:
        truths = match_groundtruth(session, gt, source).truths
        scores = newest(inference_observations(session, store, truths, rerender_max_pairs=0, relight_max_pairs=0))
        hits = dict(part_substance_hits(session, store, truths))
        if hits:
            scores["substances"] = {"substance_accuracy": hits}
        return scores


def newest(by_key: dict) -> dict:
    """Each method's observations at its newest classifier, keyed by the method's name."""
    out: dict = {}
    for key in sorted(by_key, key=lambda k: classifier_id_of(k) or -1):
        out[method_of(key)] = dict(by_key[key])
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--a", required=True, help="database URL of arm A")
    parser.add_argument("--b", required=True, help="database URL of arm B")
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--source", default="demo")
    args = parser.parse_args(argv)
    store = BlobStore(get_settings().blob_root)
    a, b = (observations(url, args.groundtruth, args.source, store) for url in (args.a, args.b))
    if not a or not b:
        print("no scored exemplar in one of the arms", file=sys.stderr)
        return 2
    print("| method | metric | A | B | B - A (95%) |\n|---|---|---|---|---|")
    for method in sorted(set(a) & set(b)):
        for metric in METRICS:
            if metric not in a[method] or metric not in b[method]:
                continue
            d = difference_interval(b[method][metric], a[method][metric])
            ma, mb = mean_interval(a[method][metric]), mean_interval(b[method][metric])
            span = "" if d.low is None else f" ({d.low:+.3f}, {d.high:+.3f})"
            print(f"| {method} | {metric} | {ma.value:.3f} | {mb.value:.3f} | {d.value:+.3f}{span} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
