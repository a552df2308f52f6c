"""Two substance networks' reads of the same photos, paired: small parts, larger parts, every part.

    python -m experiments.small_parts.compare --a A/experiments/small_parts/results.json \\
        --b B/experiments/small_parts/results.json [--rule "network (whole photo)"]

The files come from `run.py` on data roots that share their validation renders and exemplars (e.g.
a database copy whose substances stage alone was run again with another network). Several files per
arm (trainings with other seeds, read on the same photos) are pooled: each photo then holds every
training's reads of its parts. Prints, per set, B minus A with a 95% bootstrap interval over photos,
for the small parts under `--rule`, the larger parts (always the network's whole-photo vote), and
both together: the stage's per-part substance accuracy where `--rule` is the network's own vote.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from photoshape_flow.evaluation.bootstrap import difference_interval

Reads = dict[str, list[float]]  # photo -> hit (1) or miss (0) per part read


def pooled(results: list[dict[str, Any]], name: str, rule: str) -> dict[str, Reads]:
    """Per photo, every file's reads of its small parts, larger parts, and both."""
    out: dict[str, Reads] = {"small parts": {}, "larger parts": {}, "every part": {}}
    for result in results:
        by_photo = result[name]["by_photo"]
        for label, reads in (("small parts", by_photo["small"][rule]), ("larger parts", by_photo["large"])):
            for photo, hits in reads.items():
                out[label].setdefault(photo, []).extend(hits)
                out["every part"].setdefault(photo, []).extend(hits)
    return out


def mean(reads: Reads, photos: set[str]) -> float:
    hits = [hit for photo in photos for hit in reads.get(photo, [])]
    return sum(hits) / max(1, len(hits))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--a", type=Path, nargs="+", required=True)
    parser.add_argument("--b", type=Path, nargs="+", required=True)
    parser.add_argument("--rule", default="network (whole photo)")
    args = parser.parse_args()
    first, second = ([json.loads(path.read_text()) for path in paths] for paths in (args.a, args.b))
    for name in ("validation renders", "world"):
        if not all(name in result for result in first + second):
            continue
        arm_a, arm_b = pooled(first, name, args.rule), pooled(second, name, args.rule)
        for label, a in arm_a.items():
            b = arm_b[label]
            photos = set(a) & set(b)
            diff = difference_interval({k: b[k] for k in photos}, {k: a[k] for k in photos})
            count = sum(len(a[k]) for k in photos) // len(first)
            print(f"{name:18s} {label:12s} ({count}): A {mean(a, photos):.3f}  B {mean(b, photos):.3f}  "
                  f"B - A {diff.value:+.3f} ({diff.low:+.3f}, {diff.high:+.3f})")


if __name__ == "__main__":
    main()
