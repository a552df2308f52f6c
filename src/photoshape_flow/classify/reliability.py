"""Reliability of a posterior: mean confidence against accuracy in bins, and the expected calibration error.

A posterior a user thresholds ("every part at least 0.5") is only worth it when 0.7 means right about
70% of the time. This measures that on held-out regions: the top material's posterior of each region
(`confidence`) and whether it was the true material (`correct`), binned on [0, 1]. The ECE is the
count-weighted mean gap |accuracy - mean confidence| over the bins (0: perfectly calibrated).

Pure: arrays in, numbers out.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Reliability:
    count: int
    accuracy: float | None
    mean_confidence: float | None
    ece: float | None  # None: no regions
    bins: list[dict[str, Any]] = field(default_factory=list)  # non-empty bins: lo, hi, count, confidence, accuracy

    def to_dict(self) -> dict[str, Any]:
        return {"regions": self.count, "accuracy": self.accuracy, "mean_posterior": self.mean_confidence,
                "ece": self.ece, "bins": self.bins}


def reliability(confidence: np.ndarray, correct: np.ndarray, bins: int = 10) -> Reliability:
    """Equal-width bins of `confidence` (the last one closed at 1.0), each with its accuracy."""
    conf = np.clip(np.asarray(confidence, np.float64), 0.0, 1.0)
    hit = np.asarray(correct, bool)
    if conf.size == 0:
        return Reliability(0, None, None, None)
    index = np.minimum((conf * bins).astype(np.int64), bins - 1)
    table, gap = [], 0.0
    for b in range(bins):
        inside = index == b
        n = int(inside.sum())
        if not n:
            continue
        mean_conf, accuracy = float(conf[inside].mean()), float(hit[inside].mean())
        gap += n * abs(accuracy - mean_conf)
        table.append({"lo": b / bins, "hi": (b + 1) / bins, "count": n, "confidence": round(mean_conf, 4),
                      "accuracy": round(accuracy, 4)})
    return Reliability(int(conf.size), round(float(hit.mean()), 4), round(float(conf.mean()), 4),
                       round(gap / conf.size, 4), table)
