"""Colour evidence for the material ranking: how likely a part's colour is under each material.

Why: the material classifier sees colour, but it was trained on renders and is unsure among materials
that differ mostly in hue and value; on the medium demo plain colour matching (section 6.1's
baseline) put the right material in its top 5 more often than the classifier did, while the
classifier was far better at top 1. The two are complementary, so the ranking multiplies them
(a product of experts): score = p(material | image, mask) x p(substance) x p(colour | material),
with

    p(colour | material) = exp(-dE^2 / (2 sigma^2)),

dE the CIE76 distance between the median CIELAB colour of the part and of the material's render
(the colour-matching baseline's distance). sigma is fit on the validation training renders, never
on exemplars: for every material region of those renders, the distance between its median colour and
its material's own colour measures how far lighting, texture scale and shading move a material's
colour. With dE^2 / sigma^2 ~ chi^2 with 3 degrees of freedom, the robust estimate is
sigma^2 = median(dE^2) / median(chi^2_3).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.imaging.io import load_label_map, load_rgb

if TYPE_CHECKING:
    from photoshape_flow.classify.dataset import RenderItem

log = logging.getLogger(__name__)

CHI2_3_MEDIAN = 2.365973884375338  # median of the chi-squared distribution with 3 degrees of freedom
MIN_SIGMA = 1.0  # CIELAB units: below a just-noticeable difference a likelihood this sharp means nothing


def material_lab_matrix(materials: Sequence[int], labs: Mapping[int, np.ndarray]) -> np.ndarray:
    """(M, 3) CIELAB colours in `materials` order; NaN rows where a material has no colour."""
    out = np.full((len(materials), 3), np.nan, np.float64)
    for i, mid in enumerate(materials):
        lab = labs.get(int(mid))
        if lab is not None:
            out[i] = np.asarray(lab, np.float64)
    return out


def color_likelihood(part_lab: np.ndarray | None, material_labs: np.ndarray, sigma: float) -> np.ndarray:
    """p(colour | material) for every row of `material_labs` (M, 3), in (0, 1].

    A material without a colour (NaN row) gets the mean likelihood of the others, so it is neither
    favoured nor ruled out; no part colour (None) or no material colours gives all ones.
    """
    labs = np.asarray(material_labs, np.float64)
    out = np.ones(len(labs), np.float64)
    known = ~np.isnan(labs).any(axis=1)
    if part_lab is None or not known.any():
        return out
    d2 = ((labs[known] - np.asarray(part_lab, np.float64)[None]) ** 2).sum(axis=1)
    out[known] = np.exp(-d2 / (2.0 * max(float(sigma), MIN_SIGMA) ** 2))
    out[~known] = out[known].mean()
    return out


def fit_color_sigma(distances: Sequence[float] | np.ndarray) -> float | None:
    """Robust maximum-likelihood sigma of an isotropic 3-D Gaussian from CIE76 distances (None: no data)."""
    d = np.asarray(distances, np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return None
    return max(float(np.sqrt(np.median(d**2) / CHI2_3_MEDIAN)), MIN_SIGMA)


def region_color_distances(
    items: Sequence[RenderItem],
    material_labs: Mapping[int, np.ndarray],
    *,
    min_fraction: float = 0.005,
    limit: int | None = None,
) -> np.ndarray:
    """CIE76 distance of each material region of `items` from its material's colour.

    Regions smaller than `min_fraction` of the image (the classifier's own threshold) and materials
    without a colour are skipped; unreadable renders are logged and skipped. `limit` caps the renders
    read (in the given order, so the result is stable).
    """
    distances: list[float] = []
    for item in list(items)[: limit if limit is not None else None]:
        try:
            ids = load_label_map(item.material_map)
            rgb = load_rgb(item.image)
        except (ValueError, OSError) as exc:
            log.warning("%s", exc)
            continue
        if ids.shape != rgb.shape[:2]:
            log.warning("%s: image and material map differ in size; skipped", item.image)
            continue
        minimum = max(1, int(np.ceil(min_fraction * ids.size)))
        values, counts = np.unique(ids, return_counts=True)
        for value, count in zip(values.tolist(), counts.tolist(), strict=True):
            target = material_labs.get(int(value))
            if value == 0 or count < minimum or target is None:
                continue
            lab = median_lab(rgb, ids == value)
            if lab is not None:
                distances.append(float(np.linalg.norm(lab - np.asarray(target, np.float64))))
    return np.asarray(distances, np.float64)
