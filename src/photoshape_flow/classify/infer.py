"""Material classifier inference (sections 5.2 "Inference" and 6.5 "Image-based SVBRDF retrieval").

`load_classifier(checkpoint)` rebuilds the network of a checkpoint (bytes, path or dict) in eval mode
on the configured device. `MaterialClassifier.predict(image, masks)` classifies each masked region
of one image in batches and returns softmax probabilities of both heads; `top_k` ranks materials,
by default weighting each material's probability by the predicted probability of its substance
("we are able to improve material prediction performance by weighting the material prediction by
the confidence of the corresponding substance category prediction"). The background class is never
ranked.

Non-square images are padded to a square with white (the training renders are square, object on
white) or, with ``crop="mask"``, cut to a square around the region's bounding box with some context,
which suits photos where the object is small.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.dataset import make_input
from photoshape_flow.classify.resnet import MaterialResNet
from photoshape_flow.classify.train import material_substance_index
from photoshape_flow.devices import resolve_device
from photoshape_flow.vocab import SUBSTANCE_LABELS

CropMode = Literal["image", "mask"]


@dataclass(frozen=True)
class Ranked:
    """One ranked material for a region."""

    material_id: int
    substance: str
    score: float  # ranking score (substance-weighted probability unless weighting is off)
    probability: float  # the material head's softmax probability


def substance_first_order(scores: np.ndarray, substances: Sequence[str], substance: str | None = None) -> np.ndarray:
    """Material indices for one region, best first, deciding the substance before the material.

    The first material is the best-scoring one of the substance with the most ranking mass (the sum
    of its materials' scores); the others follow by score. Why: the scores are an (unnormalised)
    posterior over materials, and the substance that posterior believes most is the sum over the
    substance's materials, not the substance of the single best material, which a cluster of
    similar materials of another substance can outvote by splitting the mass. Choosing the
    substance first is the Bayes decision for the substance and costs the material ranking nothing
    measurable (docs/results.md, bench/substance_weighting.py). A given `substance` (one decided by
    other evidence) is taken instead, when any of its materials has a positive score.
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(substances)
    order = np.argsort(-scores, kind="stable")
    if order.size == 0:
        return order
    mass = {name: float(scores[labels == name].sum()) for name in dict.fromkeys(labels.tolist())}
    best = max(mass, key=lambda name: mass[name])  # ties: the first substance in material order
    if substance is not None and mass.get(substance, 0.0) > 0.0:
        best = substance
    first = next(int(i) for i in order if labels[i] == best)
    return np.concatenate([[first], order[order != first]]).astype(np.int64)


def _square(image: np.ndarray, mask: np.ndarray, crop: CropMode, context: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Pad (white / 0) or crop around the mask to a square, keeping the region fully inside."""
    height, width = mask.shape
    if crop == "mask" and mask.any():
        ys, xs = np.nonzero(mask)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        side = int(round(max(y1 - y0, x1 - x0) * (1 + context)))
        cy, cx = (y0 + y1) // 2, (x0 + x1) // 2
        top, left = cy - side // 2, cx - side // 2
    else:
        side = max(height, width)
        top, left = (height - side) // 2, (width - side) // 2
    if side <= 0:
        raise ValueError("empty image")
    out_img = np.full((side, side, image.shape[2]), 255 if image.dtype == np.uint8 else 1.0, dtype=image.dtype)
    out_mask = np.zeros((side, side), dtype=bool)
    sy0, sx0 = max(top, 0), max(left, 0)
    sy1, sx1 = min(top + side, height), min(left + side, width)
    out_img[sy0 - top:sy1 - top, sx0 - left:sx1 - left] = image[sy0:sy1, sx0:sx1]
    out_mask[sy0 - top:sy1 - top, sx0 - left:sx1 - left] = mask[sy0:sy1, sx0:sx1]
    return out_img, out_mask


class MaterialClassifier:
    """A trained material classifier ready for inference (eval mode, no autograd)."""

    def __init__(
        self,
        model: MaterialResNet,
        materials: Sequence[int],
        material_substances: Sequence[str],
        image_size: int,
        device: torch.device | str = "cpu",
        batch_size: int = 32,
        flip: bool = True,
    ):
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.materials = [int(m) for m in materials]
        self.material_substances = list(material_substances)
        self.image_size = int(image_size)
        self.batch_size = int(batch_size)
        self.flip = bool(flip)
        self._substance_index = material_substance_index(self.material_substances)

    @property
    def num_materials(self) -> int:
        return len(self.materials)

    def inputs(self, image_rgb: np.ndarray, masks: Sequence[np.ndarray], crop: CropMode = "image") -> torch.Tensor:
        """The (K, 4, S, S) network input for K region masks of one RGB image."""
        image = np.asarray(image_rgb)
        if image.ndim != 3 or image.shape[2] < 3:
            raise ValueError(f"expected an RGB image (H, W, 3), got shape {image.shape}")
        image = image[..., :3]
        tensors = []
        for mask in masks:
            mask = np.asarray(mask).astype(bool)
            if mask.shape != image.shape[:2]:
                raise ValueError(f"mask shape {mask.shape} differs from image shape {image.shape[:2]}")
            square_img, square_mask = _square(image, mask, crop)
            tensors.append(make_input(square_img, square_mask, self.image_size))
        return torch.stack(tensors) if tensors else torch.zeros(0, 4, self.image_size, self.image_size)

    @torch.inference_mode()
    def predict(
        self, image_rgb: np.ndarray, masks: Sequence[np.ndarray], crop: CropMode = "image"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Softmax probabilities per mask: materials (K, |M| + 1) and substances (K, len(SUBSTANCE_LABELS)).

        Column 0 of both is background; material column i is `self.materials[i - 1]`. With `flip`
        (the default) each region is also classified mirrored and the two softmaxes averaged: a
        material does not depend on left and right, training used flips, and the mean of two equally
        valid views is a steadier estimate for one more forward pass.
        """
        x = self.inputs(image_rgb, masks, crop)
        mats, subs = [], []
        for start in range(0, len(x), self.batch_size):
            batch = x[start:start + self.batch_size].to(self.device)
            n = len(batch)
            if self.flip:
                batch = torch.cat([batch, batch.flip(-1)])
            mat_logits, sub_logits = self.model(batch)
            mat, sub = mat_logits.softmax(1).float().cpu(), sub_logits.softmax(1).float().cpu()
            if self.flip:
                mat, sub = 0.5 * (mat[:n] + mat[n:]), 0.5 * (sub[:n] + sub[n:])
            mats.append(mat)
            subs.append(sub)
        if not mats:
            return np.zeros((0, self.num_materials + 1), np.float32), np.zeros((0, len(SUBSTANCE_LABELS)), np.float32)
        return torch.cat(mats).numpy(), torch.cat(subs).numpy()

    def scores(
        self, material_probs: np.ndarray, substance_probs: np.ndarray | None = None,
        color_weights: np.ndarray | None = None,
    ) -> np.ndarray:
        """Ranking scores (K, |M|) of the materials (background dropped).

        Multiplied by the substance confidence when `substance_probs` (K, 6) is given, and by the
        colour likelihood (`classify.color_prior`) when `color_weights` (K, |M|) is given.
        """
        probs = np.asarray(material_probs)[:, 1:]
        if substance_probs is not None:
            probs = probs * np.asarray(substance_probs)[:, self._substance_index[1:].numpy()]
        if color_weights is not None:
            probs = probs * np.asarray(color_weights)
        return probs

    def top_k(
        self,
        material_probs: np.ndarray,
        substance_probs: np.ndarray | None = None,
        k: int = 10,
        weight_by_substance: bool = True,
        color_weights: np.ndarray | None = None,
        substance_first: bool = False,
        substances: Sequence[str | None] | None = None,
    ) -> list[list[Ranked]]:
        """The k best materials per region, best first.

        With `substance_first` the first material is chosen within the substance of most ranking
        mass (`substance_first_order`; what inference and retrieval do), or within the region's
        entry of `substances` where that is given and not None, else by score alone.
        """
        scores = self.scores(material_probs, substance_probs if weight_by_substance else None, color_weights)
        probs = np.asarray(material_probs)[:, 1:]
        results = []
        for row in range(scores.shape[0]):
            if substance_first:
                decided = substances[row] if substances is not None else None
                order = substance_first_order(scores[row], self.material_substances, decided)[: max(0, k)]
            else:
                order = np.argsort(-scores[row], kind="stable")[: max(0, k)]
            results.append([
                Ranked(self.materials[i], self.material_substances[i], float(scores[row, i]), float(probs[row, i]))
                for i in order
            ])
        return results

    def rank(
        self, image_rgb: np.ndarray, masks: Sequence[np.ndarray], k: int = 10, weight_by_substance: bool = True,
        crop: CropMode = "image",
    ) -> list[list[Ranked]]:
        """`predict` then `top_k`: the retrieval of section 6.5."""
        mat, sub = self.predict(image_rgb, masks, crop)
        return self.top_k(mat, sub, k=k, weight_by_substance=weight_by_substance)


def load_classifier(
    checkpoint: bytes | str | Path | dict[str, Any], device: torch.device | str = "auto", batch_size: int = 32
) -> MaterialClassifier:
    """A `MaterialClassifier` from a checkpoint (bytes, file or already-loaded dict)."""
    data = checkpoint if isinstance(checkpoint, dict) else ckpt.load(checkpoint)
    model = ckpt.build_model(data)
    resolved = resolve_device(device) if isinstance(device, str) else device
    return MaterialClassifier(
        model, data["materials"], data["material_substances"], data["image_size"], device=resolved,
        batch_size=batch_size,
    )
