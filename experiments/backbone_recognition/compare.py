"""Paired differences between arms of `run.py` (same validation regions), 95% bootstrap over renders.

    python -m experiments.backbone_recognition.compare arms.json BASE ARM [ARM ...]
"""

from __future__ import annotations

import json
import sys

import numpy as np

METRICS = ("top1", "top5", "substance_head", "substance_mass")


def paired(base: np.ndarray, other: np.ndarray, draws: int = 2000) -> dict[str, list[float]]:
    """other - base per metric: the mean and a 95% interval, resampling renders (column 0)."""
    if base.shape != other.shape or not np.array_equal(base[:, 0], other[:, 0]):
        raise ValueError("arms were scored on different regions")
    groups = base[:, 0].astype(int)
    unique = np.unique(groups)
    index = {g: np.nonzero(groups == g)[0] for g in unique}
    rng = np.random.default_rng(0)
    out = {}
    for j, name in enumerate(METRICS, start=1):
        diff = other[:, j] - base[:, j]
        boot = [diff[np.concatenate([index[g] for g in rng.choice(unique, len(unique))])].mean() for _ in range(draws)]
        out[name] = [round(float(diff.mean()), 3), round(float(np.percentile(boot, 2.5)), 3),
                     round(float(np.percentile(boot, 97.5)), 3)]
    return out


def main() -> None:
    path, base, *arms = sys.argv[1:]
    results = {}
    for file in path.split(","):
        with open(file) as handle:
            results.update(json.load(handle))
    reference = np.asarray(results[base]["hits"])
    for arm in arms:
        print(f"{arm} - {base}: {json.dumps(paired(reference, np.asarray(results[arm]['hits'])))}")


if __name__ == "__main__":
    main()
