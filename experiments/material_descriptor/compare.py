"""Paired differences between two arms of `run.py` over the same regions, with 95% bootstrap intervals.

    python -m experiments.material_descriptor.compare arms.json heads descriptor [--world] [--late]

Regions are resampled by render (or by photo with ``--world``), so the interval is of the difference
on the same images, not of two independent means.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

COLUMNS = ("top1", "top5", "substance_top", "substance_mass")  # hit columns 2.. of run.py's rows


def paired(a: np.ndarray, b: np.ndarray, draws: int = 2000) -> dict[str, list[float]]:
    """Mean of b - a per column and its 95% interval, resampling the images (column 0) with replacement."""
    if a.shape != b.shape or not np.array_equal(a[:, :2], b[:, :2]):
        raise SystemExit("the arms were not scored on the same regions")
    groups = a[:, 0].astype(int)
    unique = np.unique(groups)
    rows = {g: np.nonzero(groups == g)[0] for g in unique}
    rng = np.random.default_rng(0)
    diff = b[:, 2:] - a[:, 2:]
    boot = np.array([diff[np.concatenate([rows[g] for g in rng.choice(unique, len(unique))])].mean(0)
                     for _ in range(draws)])
    low, high = np.percentile(boot, [2.5, 97.5], axis=0)
    return {name: [round(float(d), 3), round(float(lo), 3), round(float(hi), 3)]
            for name, d, lo, hi in zip(COLUMNS, diff.mean(0), low, high, strict=True)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("arms")
    parser.add_argument("base")
    parser.add_argument("other")
    parser.add_argument("--world", action="store_true", help="the world's photos instead of the validation renders")
    parser.add_argument("--late", action="store_true", help="only the regions of the late materials")
    args = parser.parse_args()
    results = json.loads(open(args.arms).read())

    def hits(arm: str) -> np.ndarray:
        if arm not in results:
            raise SystemExit(f"{args.arms}: no arm {arm!r}; arms: {', '.join(k for k in results if k != 'late')}")
        record = results[arm]["world"] if args.world else results[arm]
        data = np.asarray(record["hits"], float)
        return data[data[:, 1] == 1] if args.late else data

    a, b = hits(args.base), hits(args.other)
    print(json.dumps({"regions": len(a), f"{args.other} - {args.base}": paired(a, b)}))


if __name__ == "__main__":
    main()
