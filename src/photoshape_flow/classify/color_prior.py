"""Colour evidence for the material ranking: how likely a part's colour is under each material.

Why: the material classifier sees colour, but it was trained on renders and is unsure among materials
that differ mostly in hue and value; on the medium demo plain colour matching (section 6.1's
baseline) put the right material in its top 5 more often than the classifier did, while the
classifier was far better at top 1. The two are complementary, so the ranking multiplies them
(a product of experts): score = p(material | image, mask) x p(substance) x p(colour | material),
with

    p(colour | material) = exp(-dE^2 / (2 sigma^2)),

dE the CIE76 distance between the median CIELAB colour of the part and the material's colour: its
median colour in the training renders (`rendered_material_labs`, D63), else its preview's. sigma is
fit on validation renders made photo-like (`recognition.calibration`), never on exemplars: for every
material region of those renders, the distance between its median colour and its material's colour
measures how far lighting, texture scale, shading and a photo's imaging move a material's colour.
With dE^2 / sigma^2 ~ chi^2 with 3 degrees of freedom, the robust estimate is
sigma^2 = median(dE^2) / median(chi^2_3).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.imaging.io import load_label_map, load_rgb

if TYPE_CHECKING:
    from photoshape_flow.classify.dataset import RenderItem

log = logging.getLogger(__name__)

CHI2_3_MEDIAN = 2.365973884375338  # median of the chi-squared distribution with 3 degrees of freedom
MIN_SIGMA = 1.0  # CIELAB units: below a just-noticeable difference a likelihood this sharp means nothing
MIN_RENDERED_REGIONS = 3  # regions in the training renders below which a material keeps its preview colour


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


def region_labs(rgb: np.ndarray, labels: np.ndarray, min_fraction: float = 0.005) -> list[tuple[int, np.ndarray]]:
    """(label, median CIELAB) of every non-zero label of `labels` covering at least `min_fraction` of the image."""
    minimum = max(1, int(np.ceil(min_fraction * labels.size)))
    values, counts = np.unique(labels, return_counts=True)
    out = []
    for value, count in zip(values.tolist(), counts.tolist(), strict=True):
        if value != 0 and count >= minimum and (lab := median_lab(rgb, labels == value)) is not None:
            out.append((int(value), lab))
    return out


def render_region_labs(items: Sequence[RenderItem], *, min_fraction: float = 0.005,
                       limit: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """(material id, median CIELAB) of each material region of `items` (see `region_labs`).

    Unreadable renders are logged and skipped; `limit` caps the renders read, in the given order, so
    the result is stable.
    """
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
        yield from region_labs(rgb, ids, min_fraction)


def region_color_distances(
    items: Sequence[RenderItem],
    material_labs: Mapping[int, np.ndarray],
    *,
    min_fraction: float = 0.005,
    limit: int | None = None,
) -> np.ndarray:
    """CIE76 distance of each material region of `items` from its material's colour.

    Regions smaller than `min_fraction` of the image (the classifier's own threshold) and materials
    without a colour are skipped (`render_region_labs`).
    """
    return np.asarray([float(np.linalg.norm(lab - np.asarray(material_labs[mid], np.float64)))
                       for mid, lab in render_region_labs(items, min_fraction=min_fraction, limit=limit)
                       if mid in material_labs], np.float64)


def rendered_material_labs(items: Sequence[RenderItem], *, min_fraction: float = 0.005, limit: int | None = None,
                           min_regions: int = MIN_RENDERED_REGIONS) -> dict[int, np.ndarray]:
    """Each material's colour as the training renders show it: the median of its regions' median CIELAB.

    Why not the preview: a preview is one sphere under whichever envmap sorts first, so its colour
    carries that light's tint and a sphere's shading; a material's regions in the training renders are
    seen on the collection's shapes under all its training lights, which is what a photo's part is
    compared with (D63: on the small demo the preview under a warm studio sat 11 CIELAB b* units from
    the renders under the neutral validation studio). Materials with fewer than `min_regions` regions
    are left out (the caller falls back to the preview).
    """
    found: dict[int, list[np.ndarray]] = {}
    for mid, lab in render_region_labs(items, min_fraction=min_fraction, limit=limit):
        found.setdefault(mid, []).append(lab)
    return {mid: np.median(np.stack(labs), axis=0) for mid, labs in sorted(found.items()) if len(labs) >= min_regions}
