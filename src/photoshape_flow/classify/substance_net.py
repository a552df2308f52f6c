"""A compact fully-convolutional substance segmentation network (replaces MINC, section 4.3).

The paper labelled exemplar pixels with the MINC VGG-16 network, whose weights cannot be fetched
here; this is a small U-Net with residual blocks trained on our own bootstrap renders instead:

    stem: two 3x3 convs (w channels, /2) -> residual stages 2w, 4w, 8w at /4, /8, /16
    -> global-context vector added at the bottleneck (an image-level cue: a sofa is mostly fabric)
    -> decoder: bilinear x2 + skip concat + two 3x3 convs, up to /2 -> 1x1 to 6 logits
    -> bilinear upsampling of the logits to the input size

Output: logits (N, 6, H, W) over SUBSTANCE_LABELS (0 = background). Input: RGB in [0, 1], any size
(multiples of 16 avoid resampling inside). Nothing runs at full resolution but the final upsampling:
the full-resolution decoder stage of a classic U-Net cost ~4x the compute on CPU for boundaries the
part-level majority vote does not need. ~0.6 M parameters at w=16; no pretrained weights, no
torchvision. Deliberately separate from the material classifier, whose predictions are later
weighted by this network's substance confidence (section 5.2, "Inference").
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from photoshape_flow.classify.substance_configs import SUBSTANCE_ARCHITECTURE
from photoshape_flow.vocab import SUBSTANCE_LABELS

NUM_CLASSES = len(SUBSTANCE_LABELS)
ARCHITECTURE = SUBSTANCE_ARCHITECTURE


def _conv_bn(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class ResBlock(nn.Module):
    """Basic residual block (ResNet-18 style), optionally strided."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or cin != cout:
            self.shortcut = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = F.relu(self.bn1(self.conv1(x)), inplace=True)
        out = self.bn2(self.conv2(out))
        return F.relu(out + self.shortcut(x), inplace=True)


class UpBlock(nn.Module):
    def __init__(self, cin: int, cskip: int, cout: int):
        super().__init__()
        self.body = nn.Sequential(_conv_bn(cin + cskip, cout), _conv_bn(cout, cout))

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.body(torch.cat([x, skip], dim=1))


class SubstanceNet(nn.Module):
    """Small residual U-Net: RGB (N, 3, H, W) in [0, 1] -> logits (N, 6, H, W)."""

    def __init__(self, width: int = 16, num_classes: int = NUM_CLASSES):
        super().__init__()
        w = int(width)
        self.width = w
        self.num_classes = num_classes
        self.register_buffer("mean", torch.tensor([0.5, 0.5, 0.5]).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor([0.25, 0.25, 0.25]).view(1, 3, 1, 1), persistent=False)
        self.stem = nn.Sequential(_conv_bn(3, w, stride=2), _conv_bn(w, w))  # /2
        self.enc1 = ResBlock(w, 2 * w, stride=2)  # /4
        self.enc2 = ResBlock(2 * w, 4 * w, stride=2)  # /8
        self.enc3 = ResBlock(4 * w, 8 * w, stride=2)  # /16
        self.context = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(8 * w, 8 * w, 1), nn.ReLU(inplace=True))
        self.dec2 = UpBlock(8 * w, 4 * w, 4 * w)
        self.dec1 = UpBlock(4 * w, 2 * w, 2 * w)
        self.dec0 = UpBlock(2 * w, w, w)
        self.head = nn.Conv2d(w, num_classes, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-2:]
        x = (x - self.mean) / self.std
        s0 = self.stem(x)
        s1 = self.enc1(s0)
        s2 = self.enc2(s1)
        s3 = self.enc3(s2)
        s3 = s3 + self.context(s3)
        y = self.dec2(s3, s2)
        y = self.dec1(y, s1)
        y = self.dec0(y, s0)
        return F.interpolate(self.head(y), size=size, mode="bilinear", align_corners=False)


def count_parameters(model: nn.Module) -> int:
    return int(sum(p.numel() for p in model.parameters()))
