"""Material assignment for one part: the classifier's ranking and the baselines of section 6.1.

Pure functions on arrays; `pipeline.inference` feeds them the exemplar, the aligned part masks and
the substance network's per-part probabilities, and writes the ranked results as assignment rows.

- classifier: material probabilities weighted by the substance confidence (section 5.2.4) — the
  substance confidence comes from the substance segmentation network, which is independent of the
  classifier, so the two sources of evidence combine — and, beyond the paper, by the colour
  likelihood of `classify.color_prior` (the colour-matching distance made a likelihood).
- no-classifier: a random material of the predicted substance (seeded by the pair and part, so a
  re-run draws the same), "akin to our training data generation process".
- color-match: the median colour of the exemplar's part against the median colour of each material's
  render, in CIELAB (which ignores the specularities and shading that the paper says make this fail).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from photoshape_flow.vocab import SUBSTANCE_LABELS, SUBSTANCES


@dataclass(frozen=True)
class RankedMaterial:
    material_id: int
    substance: str
    score: float
    posterior: float | None = None  # the ranking's posterior over enabled materials (ours only)


def substance_vector(probs: Mapping[str, float] | None) -> np.ndarray:
    """Substance probabilities in SUBSTANCE_LABELS order (background first), renormalised over substances."""
    vec = np.zeros(len(SUBSTANCE_LABELS), np.float64)
    if probs:
        for i, name in enumerate(SUBSTANCE_LABELS):
            vec[i] = float(probs.get(name, 0.0))
    vec[0] = 0.0
    total = vec.sum()
    if total <= 0:
        vec[1:] = 1.0 / len(SUBSTANCES)
    else:
        vec /= total
    return vec


def one_substance(substance: str) -> np.ndarray:
    vec = np.zeros(len(SUBSTANCE_LABELS), np.float64)
    vec[SUBSTANCE_LABELS.index(substance)] = 1.0
    return vec


def random_of_substance(
    substance: str | None, materials: Sequence[tuple[int, str]], seed: int, k: int = 5
) -> list[RankedMaterial]:
    """k distinct random materials of `substance` (any substance when none has materials), uniform scores."""
    pool = [(mid, sub) for mid, sub in materials if sub == substance] or list(materials)
    if not pool:
        return []
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(pool))[:k]
    return [RankedMaterial(pool[i][0], pool[i][1], 1.0 / len(pool)) for i in order]


def median_lab(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray | None:
    """Median CIELAB colour of the masked sRGB pixels (None when the mask is empty)."""
    pixels = np.asarray(rgb)[..., :3]
    if mask is not None:
        pixels = pixels[np.asarray(mask, bool)]
    pixels = pixels.reshape(-1, 3)
    if len(pixels) == 0:
        return None
    if pixels.dtype != np.uint8:
        pixels = np.clip(pixels * 255.0, 0, 255).astype(np.uint8)
    lab = cv2.cvtColor(pixels.reshape(-1, 1, 3), cv2.COLOR_RGB2LAB).reshape(-1, 3).astype(np.float64)
    lab[:, 0] *= 100.0 / 255.0  # OpenCV's 8-bit Lab: L in 0..255, a/b offset by 128
    lab[:, 1:] -= 128.0
    return np.median(lab, axis=0)


def color_match(
    part_lab: np.ndarray,
    material_labs: Mapping[int, np.ndarray],
    material_substances: Mapping[int, str],
    k: int = 5,
    substance: str | None = None,
    sigma: float = 10.0,
) -> list[RankedMaterial]:
    """Materials ranked by CIE76 distance of median colours; score = exp(-dE / sigma).

    With `substance`, only that substance's materials are ranked (used for unobserved parts).
    """
    ids = [m for m in material_labs if substance is None or material_substances.get(m) == substance]
    if not ids:
        ids = list(material_labs)
    if not ids:
        return []
    labs = np.stack([material_labs[m] for m in ids])
    distances = np.linalg.norm(labs - np.asarray(part_lab)[None], axis=1)
    order = np.argsort(distances, kind="stable")[:k]
    return [RankedMaterial(ids[i], material_substances[ids[i]], float(np.exp(-distances[i] / sigma))) for i in order]


def foreground_of_render(rgb: np.ndarray, alpha: np.ndarray | None = None, white: int = 245) -> np.ndarray:
    """Foreground mask of a render: its alpha when given, else the non-white pixels."""
    if alpha is not None:
        return np.asarray(alpha) > 0.5
    img = np.asarray(rgb)[..., :3]
    return ~np.all(img >= white, axis=-1)
