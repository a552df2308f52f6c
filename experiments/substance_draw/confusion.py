"""Substance confusion of each method's first material on an evaluation world's scored parts.

    PHOTOSHAPE_DATA_ROOT=/work/world-a python -m experiments.substance_draw.confusion \\
        --groundtruth /work/second-world/groundtruth.json --source second-world [--url sqlite:////work/arm.db]

Rows: true substance; columns: the substance of the method's rank-1 material; the last column is
recall. Parts are matched and scored as `photoshape eval` scores them (`scoring.evaluate.pair_truths`).
Measurement only: nothing here is chosen on an evaluation world.
"""

from __future__ import annotations

import argparse
from collections import Counter, defaultdict
from pathlib import Path

from experiments.common import scored_rankings
from photoshape_flow.config import get_settings
from photoshape_flow.vocab import SUBSTANCES


def confusions(url: str, groundtruth: Path, source: str) -> dict[str, Counter[tuple[str, str]]]:
    """Method key -> Counter of (true substance, rank-1 substance) over the scored parts."""
    out: dict[str, Counter[tuple[str, str]]] = defaultdict(Counter)
    for key, (_, substance), candidates in scored_rankings(url, groundtruth, source):
        rank, _, chosen, _ = candidates[0]
        if rank == 1 and chosen is not None:
            out[key][(substance, chosen)] += 1
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, required=True)
    parser.add_argument("--source", required=True, help="the exemplars' source, e.g. second-world or demo-small")
    parser.add_argument("--url", default=None, help="database URL (default: the settings')")
    args = parser.parse_args()
    url = args.url or get_settings().resolved_database_url
    for key, counts in sorted(confusions(url, args.groundtruth, args.source).items()):
        total = sum(counts.values())
        right = sum(v for (t, p), v in counts.items() if t == p)
        print(f"\n{key}: {total} parts, substance {right / total:.3f}")
        print("true \\ first " + " ".join(f"{s:>8}" for s in SUBSTANCES) + "   recall")
        for t in SUBSTANCES:
            row = [counts[(t, p)] for p in SUBSTANCES]
            n = sum(row)
            recall = f"{row[SUBSTANCES.index(t)] / n:.2f}" if n else "-"
            print(f"{t:>12} " + " ".join(f"{v:>8}" for v in row) + f"   {recall} ({n})")


if __name__ == "__main__":
    main()
