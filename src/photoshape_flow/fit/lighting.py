"""Lighting per exemplar: the envmap, rotation and exposure that best explain the photo (pure parts).

A hypothesis is one training envmap at one rotation about +y; the exposure is solved in closed form
for each (least squares in linear RGB between the rendered and the photo's per-part mean colours,
weighted by pixels: per-part means, not pixels, because the render and the photo are only aligned
up to a few pixels). The hypothesis with the lowest appearance loss of the ranking's first
materials wins (`fit.scene.estimate_lighting`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from photoshape_flow.render.specs import linear_to_srgb, srgb_to_linear

EXPOSURE_RANGE = (1.0 / 32.0, 32.0)


@dataclass(frozen=True)
class Hypothesis:
    """One lighting candidate: an envmap (row id) rotated about +y (radians)."""

    envmap_id: int
    rotation: float


def rotations(count: int) -> list[float]:
    """`count` rotations evenly spread over a turn, starting at 0."""
    return [2.0 * np.pi * i / max(1, count) for i in range(max(1, count))]


def region_means(linear: np.ndarray, masks: Mapping[int, np.ndarray]) -> dict[int, tuple[np.ndarray, int]]:
    """Mean linear RGB and pixel count of each non-empty region."""
    return {key: (linear[mask].reshape(-1, 3).mean(axis=0), int(mask.sum())) for key, mask in masks.items()
            if mask.any()}


def exposure(rendered: Mapping[int, tuple[np.ndarray, int]], photo: Mapping[int, tuple[np.ndarray, int]]) -> float:
    """The scale s minimising sum_p n_p |s r_p - f_p|^2 over the regions in both (1 when none), clamped."""
    num = den = 0.0
    for key, (r, n) in rendered.items():
        if key in photo:
            f, m = photo[key]
            w = float(min(n, m))
            num += w * float(np.dot(r, f))
            den += w * float(np.dot(r, r))
    if den <= 0.0:
        return 1.0
    return float(np.clip(num / den, *EXPOSURE_RANGE))


def exposed_srgb(linear: np.ndarray, scale: float) -> np.ndarray:
    """A linear render at an exposure, as sRGB float 0..1 (what the camera would have stored)."""
    return linear_to_srgb(np.asarray(linear, np.float64) * scale).astype(np.float32)


def photo_linear(srgb: np.ndarray) -> np.ndarray:
    """A photo (uint8 sRGB) in linear RGB, with the sRGB EOTF (not a 2.2 gamma)."""
    return srgb_to_linear(np.asarray(srgb, np.float64) / 255.0).astype(np.float32)


def best(losses: Sequence[tuple[Hypothesis, float, float]]) -> tuple[Hypothesis, float, float]:
    """The (hypothesis, exposure, loss) with the lowest finite loss; ties: the first."""
    finite = [item for item in losses if np.isfinite(item[2])]
    if not finite:
        raise ValueError("no lighting hypothesis could be scored (no part visible in both images)")
    return min(finite, key=lambda item: item[2])
