"""95% bootstrap intervals over exemplars, for a mean and for the difference of two methods' means.

Parts and pairs of one exemplar are not independent (one photo, one lighting, one alignment), so the
unit resampled is the exemplar: each resample draws exemplars with replacement and recomputes the
pooled mean (sum of the drawn exemplars' values over their count). A difference between two methods
is resampled *paired* (the same exemplars drawn for both), which is what tells whether one method
beats another on this collection or only on these particular photos. Percentile intervals, a fixed
seed (the same figures every time the same rows are evaluated), numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

RESAMPLES = 2000
LEVEL = 0.95
SEED = 0

# key of a stage evaluator's result dict holding {metric: Observations} for its means' intervals
OBSERVATIONS = "_per_exemplar"

# exemplar id -> the values observed on it (one per scored part, or one per pair)
Observations = Mapping[int, Sequence[float]]


@dataclass(frozen=True)
class Estimate:
    """A pooled mean over every observation, its interval, how many observations and exemplars."""

    value: float | None
    low: float | None
    high: float | None
    count: int
    exemplars: int


def _sums(obs: Observations, clusters: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    values = [[float(v) for v in obs.get(c, ()) if np.isfinite(v)] for c in clusters]
    return np.array([sum(v) for v in values]), np.array([len(v) for v in values], np.float64)


def _draws(n_clusters: int, resamples: int, seed: int) -> np.ndarray:
    """How often each exemplar is drawn in each resample: (resamples, n_clusters) counts."""
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, n_clusters, size=(resamples, n_clusters))
    offsets = (np.arange(resamples) * n_clusters)[:, None]
    return np.bincount((picks + offsets).ravel(), minlength=resamples * n_clusters).reshape(resamples, n_clusters)


def _interval(samples: np.ndarray, level: float) -> tuple[float | None, float | None]:
    samples = samples[np.isfinite(samples)]
    if samples.size == 0:
        return None, None
    tail = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(samples, [tail, 100.0 - tail])
    return float(low), float(high)


def mean_interval(obs: Observations, *, resamples: int = RESAMPLES, level: float = LEVEL,
                  seed: int = SEED) -> Estimate:
    """The pooled mean of every observation and its percentile interval over resampled exemplars."""
    clusters = sorted(c for c, v in obs.items() if any(np.isfinite(x) for x in v))
    sums, counts = _sums(obs, clusters)
    total = int(counts.sum())
    if total == 0:
        return Estimate(None, None, None, 0, 0)
    value = float(sums.sum() / total)
    if len(clusters) < 2:
        return Estimate(value, None, None, total, len(clusters))
    draws = _draws(len(clusters), resamples, seed)
    with np.errstate(invalid="ignore", divide="ignore"):
        samples = (draws @ sums) / (draws @ counts)
    low, high = _interval(samples, level)
    return Estimate(value, low, high, total, len(clusters))


def difference_interval(a: Observations, b: Observations, *, resamples: int = RESAMPLES, level: float = LEVEL,
                        seed: int = SEED) -> Estimate:
    """mean(a) - mean(b) with a paired interval: each resample draws the same exemplars for both.

    Only exemplars observed by both count, so a method that scored fewer photos is not compared on
    a different set; `count` is the smaller of the two observation counts over those exemplars.
    """
    clusters = sorted({c for c, v in a.items() if len(v)} & {c for c, v in b.items() if len(v)})
    sums_a, counts_a = _sums(a, clusters)
    sums_b, counts_b = _sums(b, clusters)
    keep = (counts_a > 0) & (counts_b > 0)
    sums_a, counts_a, sums_b, counts_b = sums_a[keep], counts_a[keep], sums_b[keep], counts_b[keep]
    n = int(keep.sum())
    if n == 0:
        return Estimate(None, None, None, 0, 0)
    value = float(sums_a.sum() / counts_a.sum() - sums_b.sum() / counts_b.sum())
    count = int(min(counts_a.sum(), counts_b.sum()))
    if n < 2:
        return Estimate(value, None, None, count, n)
    draws = _draws(n, resamples, seed)
    with np.errstate(invalid="ignore", divide="ignore"):
        samples = (draws @ sums_a) / (draws @ counts_a) - (draws @ sums_b) / (draws @ counts_b)
    low, high = _interval(samples, level)
    return Estimate(value, low, high, count, n)
