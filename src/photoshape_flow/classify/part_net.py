"""The part recogniser: a pretrained ImageNet backbone read over one part, with the paper's two heads.

Same contract as `classify.resnet.MaterialResNet` (input (N, 4, H, W): RGB in [0, 1] + the part's
mask; output material logits (N, |M| + 1) and substance logits (N, len(SUBSTANCE_LABELS))), so the
training loop, inference, calibration and fit's ranker use it unchanged. What differs, and why:

* **Part-level crop inside the network.** A part is 10-60 px of a 96-128 px render or a 512 px photo;
  a whole-object input would give ImageNet features of a chair, not of its leather. The square around
  the mask's bounding box (plus `context` of its side) is resampled to `crop_size` with
  ``grid_sample`` (white outside the image, as product photos and renders are on white), so every
  caller's input is read at the backbone's scale whatever its size.
* **Isolated part** (`isolate`): pixels outside the mask are painted white before the backbone, so a
  part's features depend on its own pixels only (another part's colour cannot leak in through the
  receptive field; a misaligned neighbour in a photo's part map cannot either).
* **Pooling over the mask at several depths**: per channel, the mask-weighted mean and standard
  deviation of three block outputs (fine texture at 1/8, mid-level at 1/16, object-level at 1/32) and
  the mean of the 1280-channel head, concatenated. Orderless mean/std statistics of intermediate layers
  are what texture and material recognition rests on (Cimpoi et al. 2015; Gatys et al. 2015).
* **Upper blocks fine-tuned, lower ones frozen** (`train_from_stage`): frozen features and a linear head
  were measured and do not transfer from renders to photos (shared/research/pretrained-backbones.md);
  the frozen stem and early stages keep ImageNet's generic filters (and their BatchNorm statistics stay
  ImageNet's: `train()` keeps them in eval mode).
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from photoshape_flow.classify.backbone import EfficientNetLite, load_backbone
from photoshape_flow.vocab import SUBSTANCE_LABELS

NUM_SUBSTANCE_OUTPUTS = len(SUBSTANCE_LABELS)
_EPS = 1e-6


def crop_to_mask(x: torch.Tensor, size: int, context: float) -> torch.Tensor:
    """(N, 4, H, W) -> (N, 4, size, size): the square around each mask's bounding box, `context` wider.

    Outside the image the RGB is white and the mask 0. An empty mask keeps the whole (square) frame.
    """
    n, _, h, w = x.shape
    mask = x[:, 3] > 0.5
    rows, cols = mask.any(dim=2), mask.any(dim=1)  # (N, H), (N, W)
    ar_h = torch.arange(h, device=x.device, dtype=x.dtype)
    ar_w = torch.arange(w, device=x.device, dtype=x.dtype)
    big = float(max(h, w))
    y0 = torch.where(rows, ar_h, big).amin(1)
    y1 = torch.where(rows, ar_h, -1.0).amax(1) + 1
    x0 = torch.where(cols, ar_w, big).amin(1)
    x1 = torch.where(cols, ar_w, -1.0).amax(1) + 1
    empty = ~rows.any(1)
    y0, x0 = torch.where(empty, 0.0, y0), torch.where(empty, 0.0, x0)
    y1, x1 = torch.where(empty, float(h), y1), torch.where(empty, float(w), x1)
    side = torch.maximum(y1 - y0, x1 - x0) * torch.where(empty, 1.0, 1.0 + context)
    side = side.clamp(min=4.0)
    cy, cx = (y0 + y1) / 2, (x0 + x1) / 2
    theta = torch.zeros(n, 2, 3, device=x.device, dtype=x.dtype)
    theta[:, 0, 0] = side / w
    theta[:, 1, 1] = side / h
    theta[:, 0, 2] = 2 * cx / w - 1
    theta[:, 1, 2] = 2 * cy / h - 1
    grid = F.affine_grid(theta, [n, 4, size, size], align_corners=False)
    shifted = torch.cat([x[:, :3] - 1.0, x[:, 3:]], 1)  # zero padding = white RGB, empty mask
    out = F.grid_sample(shifted, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    return torch.cat([out[:, :3] + 1.0, out[:, 3:]], 1)


def masked_moments(features: torch.Tensor, mask: torch.Tensor, std: bool) -> torch.Tensor:
    """Per-channel mean (and standard deviation) of (N, C, h, w) weighted by a (N, 1, H, W) mask."""
    weight = F.adaptive_avg_pool2d(mask, features.shape[-2:]) if mask.shape[-2:] != features.shape[-2:] else mask
    total = weight.sum((2, 3)).clamp_min(_EPS)
    mean = (features * weight).sum((2, 3)) / total
    if not std:
        return mean
    var = ((features - mean[..., None, None]) ** 2 * weight).sum((2, 3)) / total
    return torch.cat([mean, (var + _EPS).sqrt()], 1)


class PartRecognizer(nn.Module):
    """EfficientNet-Lite over a part crop, mask-pooled at several depths, material and substance heads."""

    def __init__(
        self,
        arch: str = "efficientnet-lite0",
        num_materials: int = 1,
        num_substances: int = NUM_SUBSTANCE_OUTPUTS,
        crop_size: int = 160,
        context: float = 0.25,
        isolate: bool = True,
        train_from_stage: int = 4,
        dropout: float = 0.2,
        pretrained: bool = True,
    ):
        super().__init__()
        if num_materials < 1:
            raise ValueError("the material classifier needs at least one material")
        self.arch = arch
        self.num_materials = int(num_materials)
        self.num_substances = int(num_substances)
        self.crop_size = int(crop_size)
        self.context = float(context)
        self.isolate = bool(isolate)
        self.train_from_stage = int(train_from_stage)
        self.dropout_p = float(dropout)
        self.backbone: EfficientNetLite = load_backbone(arch, weights=pretrained)
        ends = self.backbone.stage_ends
        self.taps: tuple[int | str, ...] = (ends[2], ends[4], ends[6], "head")
        channels = [self.backbone.block_channels[t] for t in self.taps[:-1]]  # type: ignore[index]
        self.feature_dim = 2 * sum(channels) + self.backbone.head_channels
        self.dropout = nn.Dropout(self.dropout_p)
        self.fc_material = nn.Linear(self.feature_dim, self.num_materials + 1)
        self.fc_substance = nn.Linear(self.feature_dim, self.num_substances)
        self._frozen = self._frozen_modules()
        for module in self._frozen:
            for p in module.parameters():
                p.requires_grad_(False)

    def _frozen_modules(self) -> list[nn.Module]:
        if self.train_from_stage <= 0:
            return []
        last_frozen = self.backbone.stage_ends[self.train_from_stage - 1]
        return [self.backbone._conv_stem, self.backbone._bn0, *self.backbone._blocks[: last_frozen + 1]]

    def train(self, mode: bool = True) -> PartRecognizer:
        super().train(mode)
        for module in self._frozen:  # frozen layers keep ImageNet's BatchNorm statistics
            module.eval()
        return self

    def prepare(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The backbone's input (N, 3, S, S) and the part mask (N, 1, S, S) at the crop."""
        if self.isolate:  # at the source resolution, so resampling cannot blend a neighbour's pixels in
            inside = (x[:, 3:] > 0.5).to(x.dtype)
            x = torch.cat([x[:, :3] * inside + (1.0 - inside), inside], 1)
        crop = crop_to_mask(x, self.crop_size, self.context)
        return crop[:, :3], crop[:, 3:]

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """The part descriptor (N, feature_dim) of a (N, 4, H, W) RGB-in-[0, 1] + mask batch."""
        rgb, mask = self.prepare(x)
        maps = self.backbone.forward_taps(rgb, self.taps)
        pooled = [masked_moments(f, mask, std=tap != "head") for f, tap in zip(maps, self.taps, strict=True)]
        return torch.cat(pooled, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        feats = self.dropout(self.features(x))
        return self.fc_material(feats), self.fc_substance(feats)

    def head_parameters(self) -> list[nn.Parameter]:
        """The parameters that start from random (trained at the full step)."""
        return [*self.fc_material.parameters(), *self.fc_substance.parameters()]

    def parameter_groups(self, weight_decay: float, backbone_lr_scale: float) -> list[dict[str, Any]]:
        """Trainable backbone blocks at a smaller step than the new heads (which start from random)."""
        heads = self.head_parameters()
        head_ids = {id(p) for p in heads}
        body = [p for p in self.parameters() if p.requires_grad and id(p) not in head_ids]
        return [{"params": heads, "weight_decay": weight_decay, "lr_scale": 1.0},
                {"params": body, "weight_decay": weight_decay, "lr_scale": backbone_lr_scale}]

    def spec(self) -> dict[str, object]:
        """Constructor arguments, stored in checkpoints (rebuilt without the weights package: the
        checkpoint's state dict holds every weight)."""
        return {"arch": self.arch, "num_materials": self.num_materials, "num_substances": self.num_substances,
                "crop_size": self.crop_size, "context": self.context, "isolate": self.isolate,
                "train_from_stage": self.train_from_stage, "dropout": self.dropout_p}
