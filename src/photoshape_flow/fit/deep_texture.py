"""Deep texture statistics of a region: an ImageNet backbone's feature moments over the part's mask.

Colour, contrast, gradient and highlight statistics (`fit.appearance`) see how bright, how varied and
how glossy a region is, not what pattern it carries: a mottled fabric, a wood grain and a brushed
metal of one colour and contrast read alike. The early and middle layers of an ImageNet network
respond to such patterns, and the per-channel mean and standard deviation of their responses over a
region summarise its texture while ignoring where each pixel lies (Gatys et al. 2015; the texture
half of DISTS, Ding et al. 2020), which is what a comparison between a render and a photo that are
only aligned up to a few pixels needs.

The frame's feature maps come from a frozen backbone (`classify.feature_maps.FeatureMaps`, injected
by the stage: this module stays numpy); each part's statistics are pooled from them with its mask, so
one forward serves every part of a render. The distance
is one minus DISTS' texture similarity: per layer and channel, (2 m_a m_b + c) / (m_a^2 + m_b^2 + c)
for the means and the same for the standard deviations, averaged: 0 for identical statistics (the
blocks' outputs are linear bottlenecks, so means of opposite sign can push it up to 2).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

MIN_WEIGHT = 1.0  # mask weight (in cells of a tap) below which a tap says nothing about the region
SIMILARITY_EPS = 1e-6  # DISTS' constant: a channel silent in both regions counts as identical


@dataclass(frozen=True)
class DeepStats:
    """Per tap, the region's per-channel feature mean and standard deviation (both (C,) float64)."""

    means: tuple[np.ndarray, ...]
    stds: tuple[np.ndarray, ...]


def _pool_weights(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The mask's coverage of each cell of an (h, w) map (an area average)."""
    h, w = int(shape[0]), int(shape[1])
    return cv2.resize(np.asarray(mask, np.float32), (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)


def deep_stats(maps: Sequence[np.ndarray], mask: np.ndarray) -> DeepStats | None:
    """The region's `DeepStats` from a frame's (C, h, w) feature maps; None when a tap sees too little of it.

    `mask` is at the frame's resolution; each cell counts by the share of it the region covers, so
    cells on the region's border count partly.
    """
    means, stds = [], []
    for features in maps:
        weight = _pool_weights(mask, features.shape[-2:])
        total = float(weight.sum())
        if total < MIN_WEIGHT:
            return None
        flat = features.reshape(features.shape[0], -1).astype(np.float64)
        w = weight.reshape(-1) / total
        mean = flat @ w
        var = np.maximum((flat * flat) @ w - mean * mean, 0.0)
        means.append(mean)
        stds.append(np.sqrt(var))
    return DeepStats(tuple(means), tuple(stds))


def _similarity(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean((2.0 * a * b + SIMILARITY_EPS) / (a * a + b * b + SIMILARITY_EPS)))


def deep_distance(a: DeepStats, b: DeepStats) -> float:
    """1 - DISTS' texture similarity of two regions' statistics: 0 when identical."""
    per_tap = [0.5 * (_similarity(ma, mb) + _similarity(sa, sb))
               for ma, mb, sa, sb in zip(a.means, b.means, a.stds, b.stds, strict=True)]
    return float(1.0 - np.mean(per_tap))
