"""Material classifier inference (sections 5.2 "Inference" and 6.5 "Image-based SVBRDF retrieval").

`load_classifier(checkpoint)` rebuilds the network of a checkpoint (bytes, path or dict) in eval mode
on the configured device. `MaterialClassifier.predict(image, masks)` classifies each masked region
of one image in batches and returns softmax probabilities of both heads; `classify.ranking` turns
them (with the other evidence) into ranked materials under `MaterialClassifier.policy()`. The
background class is never ranked.

Non-square images are padded to a square with white (the training renders are square, object on
white) or, with ``crop="mask"``, cut to a square around the region's bounding box with some context,
which suits photos where the object is small.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.bn_adapt import adapted_batchnorm
from photoshape_flow.classify.dataset import make_input
from photoshape_flow.classify.networks import MaterialNetwork
from photoshape_flow.classify.ranking import RankingPolicy
from photoshape_flow.devices import resolve_device
from photoshape_flow.vocab import SUBSTANCE_LABELS

CropMode = Literal["image", "mask"]


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
        model: MaterialNetwork,
        materials: Sequence[int],
        material_substances: Sequence[str],
        image_size: int,
        device: torch.device | str = "cpu",
        batch_size: int = 32,
        flip: bool = True,
        bn_prior: float | None = None,
    ):
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.materials = [int(m) for m in materials]
        self.material_substances = list(material_substances)
        self.image_size = int(image_size)
        self.batch_size = int(batch_size)
        self.flip = bool(flip)
        self.bn_prior = None if bn_prior is None else float(bn_prior)

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
        valid views is a steadier estimate for one more forward pass. With `bn_prior` set, the
        BatchNorm statistics are mixed with this image's own (`classify.bn_adapt`): the regions of
        one padded image are one sample, the crops of ``crop="mask"`` one each.
        """
        x = self.inputs(image_rgb, masks, crop)
        mats, subs = [], []
        for start in range(0, len(x), self.batch_size):
            batch = x[start:start + self.batch_size].to(self.device)
            n = len(batch)
            if self.flip:
                batch = torch.cat([batch, batch.flip(-1)])
            with adapted_batchnorm(self.model, self.bn_prior, 1 if crop == "image" else n) as model:
                mat_logits, sub_logits = model(batch)
            mat, sub = mat_logits.softmax(1).float().cpu(), sub_logits.softmax(1).float().cpu()
            if self.flip:
                mat, sub = 0.5 * (mat[:n] + mat[n:]), 0.5 * (sub[:n] + sub[n:])
            mats.append(mat)
            subs.append(sub)
        if not mats:
            return np.zeros((0, self.num_materials + 1), np.float32), np.zeros((0, len(SUBSTANCE_LABELS)), np.float32)
        return torch.cat(mats).numpy(), torch.cat(subs).numpy()

    def policy(self, min_region_fraction: float = 0.0, substance_first: bool = True,
               enabled: Collection[int] | None = None) -> RankingPolicy:
        """The ranking policy over this classifier's materials (`classify.ranking.rank_part` applies it)."""
        return RankingPolicy(tuple(self.materials), tuple(self.material_substances), substance_first,
                             min_region_fraction, enabled)


def load_classifier(
    checkpoint: bytes | str | Path | dict[str, Any], device: torch.device | str = "auto", batch_size: int = 32,
    bn_prior: float | None = None,
) -> MaterialClassifier:
    """A `MaterialClassifier` from a checkpoint (bytes, file or already-loaded dict); `bn_prior`: see `predict`."""
    data = checkpoint if isinstance(checkpoint, dict) else ckpt.load(checkpoint)
    model = ckpt.build_model(data)
    resolved = resolve_device(device) if isinstance(device, str) else device
    return MaterialClassifier(
        model, data["materials"], data["material_substances"], data["image_size"], device=resolved,
        batch_size=batch_size, bn_prior=bn_prior,
    )
