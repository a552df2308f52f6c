"""The material classifier network of section 5.2: a ResNet with a 4th (mask) input channel and two heads.

The backbone is written here (no torchvision: its wheels pull CUDA torch) with torchvision's module
names, so its state-dict keys are torchvision's (``conv1``, ``bn1``, ``layer1..4`` of ``BasicBlock``
with ``conv1/bn1/conv2/bn2/downsample.0/.1``) and ImageNet weights saved by torchvision
(``resnet34-*.pth``) load directly. torchvision's ``fc`` is replaced by two heads:

* ``fc_material``: |M| + 1 outputs, index 0 = background, index i = the i-th material of the
  classifier's material list (the `Classifier.materials` order, "C + 1 categories" in the paper);
* ``fc_substance``: ``len(SUBSTANCE_LABELS)`` outputs in ``vocab.SUBSTANCE_LABELS`` order (background
  first, then the five substances of section 4.3), the auxiliary task of the multitask loss.

Input: (N, 4, H, W) float, RGB in [0, 1] (sRGB, as rendered or photographed) and a binary mask of the
region to classify. ImageNet normalisation of the RGB channels happens inside `forward` (a buffer that
is not part of the state dict), so callers never normalise. The mask filters of ``conv1`` start from a
Gaussian (paper: "initialized with a random Gaussian"): with pretrained RGB filters its standard
deviation matches theirs, otherwise it is He-normal like the rest.

`grow_material_head` maps an old material head onto a new material list by material id, so adding
materials is a fine-tune rather than a full retrain.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch
from torch import nn

from photoshape_flow.vocab import SUBSTANCE_LABELS

log = logging.getLogger(__name__)

ARCHITECTURES: dict[str, tuple[int, int, int, int]] = {
    "resnet18": (2, 2, 2, 2),
    "resnet34": (3, 4, 6, 3),
}

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

BACKGROUND = 0  # output index of the background class in both heads
NUM_SUBSTANCE_OUTPUTS = len(SUBSTANCE_LABELS)


def _conv3x3(inplanes: int, planes: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(inplanes, planes, kernel_size=3, stride=stride, padding=1, bias=False)


class BasicBlock(nn.Module):
    """torchvision's ResNet basic block (two 3x3 convolutions and a residual)."""

    expansion = 1

    def __init__(self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None):
        super().__init__()
        self.conv1 = _conv3x3(inplanes, planes, stride)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(planes, planes)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class MaterialResNet(nn.Module):
    """ResNet-18/34 over RGB + mask with a material head and a substance head.

    `num_materials` counts materials only; the material head has one more output (background).
    `width` is the channel count of the stem (64 in torchvision); a narrower net keeps the same keys
    for CI-sized models but cannot take ImageNet weights.
    """

    def __init__(
        self,
        arch: str = "resnet34",
        num_materials: int = 1,
        num_substances: int = NUM_SUBSTANCE_OUTPUTS,
        width: int = 64,
        in_channels: int = 4,
    ):
        super().__init__()
        if arch not in ARCHITECTURES:
            raise ValueError(f"unknown architecture {arch!r}; expected one of {sorted(ARCHITECTURES)}")
        if num_materials < 1:
            raise ValueError("the material classifier needs at least one material")
        self.arch = arch
        self.width = width
        self.in_channels = in_channels
        self.num_materials = num_materials
        self.num_substances = num_substances
        self.register_buffer("rgb_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("rgb_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

        self.inplanes = width
        self.conv1 = nn.Conv2d(in_channels, width, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        blocks = ARCHITECTURES[arch]
        self.layer1 = self._make_layer(width, blocks[0])
        self.layer2 = self._make_layer(width * 2, blocks[1], stride=2)
        self.layer3 = self._make_layer(width * 4, blocks[2], stride=2)
        self.layer4 = self._make_layer(width * 8, blocks[3], stride=2)
        self.avgpool = nn.AdaptiveAvgPool2d((1, 1))
        self.feature_dim = width * 8 * BasicBlock.expansion
        self.fc_material = nn.Linear(self.feature_dim, num_materials + 1)
        self.fc_substance = nn.Linear(self.feature_dim, num_substances)
        self._init_weights()

    def _make_layer(self, planes: int, blocks: int, stride: int = 1) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes * BasicBlock.expansion:
            downsample = nn.Sequential(
                nn.Conv2d(self.inplanes, planes * BasicBlock.expansion, kernel_size=1, stride=stride, bias=False),
                nn.BatchNorm2d(planes * BasicBlock.expansion),
            )
        layers = [BasicBlock(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes * BasicBlock.expansion
        layers += [BasicBlock(self.inplanes, planes) for _ in range(1, blocks)]
        return nn.Sequential(*layers)

    def _init_weights(self) -> None:
        # torchvision's initialisation; conv1's mask filters are He-normal Gaussians as well.
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled backbone features (N, feature_dim) of a (N, 4, H, W) RGB-in-[0, 1] + mask batch."""
        rgb = (x[:, :3] - self.rgb_mean) / self.rgb_std
        x = torch.cat([rgb, x[:, 3:]], dim=1)
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return torch.flatten(self.avgpool(x), 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(material logits (N, |M| + 1), substance logits (N, len(SUBSTANCE_LABELS)))."""
        feats = self.features(x)
        return self.fc_material(feats), self.fc_substance(feats)

    def spec(self) -> dict[str, object]:
        """Constructor arguments, stored in checkpoints to rebuild the model."""
        return {
            "arch": self.arch,
            "num_materials": self.num_materials,
            "num_substances": self.num_substances,
            "width": self.width,
            "in_channels": self.in_channels,
        }


def build_model(
    arch: str,
    num_materials: int,
    *,
    width: int = 64,
    pretrained: str | Path | None = None,
    seed: int | None = None,
) -> MaterialResNet:
    """A fresh classifier; RGB filters from a torchvision-format ImageNet file when `pretrained` is set."""
    with torch.random.fork_rng(devices=[]):  # seed the initialisation without touching the global RNG
        if seed is not None:
            torch.manual_seed(seed)
        model = MaterialResNet(arch, num_materials=num_materials, width=width)
        if pretrained:
            load_pretrained_backbone(model, pretrained)
    return model


def load_pretrained_backbone(model: MaterialResNet, path: str | Path) -> None:
    """Copy ImageNet weights from a torchvision state dict (.pth) into the backbone.

    conv1's RGB filters are copied and its mask filters redrawn from a Gaussian with the RGB filters'
    standard deviation; torchvision's ``fc`` is ignored (the heads stay freshly initialised).
    """
    source = Path(path)
    if not source.is_file():
        raise FileNotFoundError(f"{source}: pretrained weights file not found")
    state = torch.load(source, map_location="cpu", weights_only=True)
    for wrapper in ("state_dict", "model"):
        if isinstance(state, Mapping) and wrapper in state and isinstance(state[wrapper], Mapping):
            state = state[wrapper]
    state = {k.removeprefix("module."): v for k, v in state.items()}
    own = model.state_dict()
    conv1 = state.get("conv1.weight")
    if conv1 is None or conv1.shape[1] != 3 or conv1.shape[0] != own["conv1.weight"].shape[0]:
        raise ValueError(f"{source}: not torchvision {model.arch} weights of width {model.width} (conv1 mismatch)")
    new_state = {}
    for key, value in own.items():
        if key.startswith(("fc_material.", "fc_substance.")):
            new_state[key] = value
            continue
        if key == "conv1.weight":
            weight = value.clone()
            weight[:, :3] = conv1
            std = float(conv1.std())
            weight[:, 3:] = torch.randn_like(weight[:, 3:]) * std
            new_state[key] = weight
            continue
        if key not in state or state[key].shape != value.shape:
            raise ValueError(f"{source}: missing or mis-shaped {key}; expected torchvision {model.arch} weights")
        new_state[key] = state[key]
    model.load_state_dict(new_state)
    log.info("loaded ImageNet backbone weights from %s", source)


def grow_material_head(
    model: MaterialResNet,
    old_material_ids: Sequence[int],
    new_material_ids: Sequence[int],
    substance_of: Mapping[int, str] | None = None,
    generator: torch.Generator | None = None,
) -> MaterialResNet:
    """Re-map the material head from `old_material_ids` to `new_material_ids` (both without background).

    Rows of materials in both lists keep their trained weights (moved to their new index), the
    background row is kept, materials no longer listed are dropped, and each new material's row
    starts at the mean of the old rows of its substance (all old rows when none share it or
    `substance_of` is not given) plus a little noise, so new classes start competitive rather than
    far below the trained ones. Modifies and returns `model`.
    """
    old_ids = [int(i) for i in old_material_ids]
    new_ids = [int(i) for i in new_material_ids]
    head = model.fc_material
    if head.out_features != len(old_ids) + 1:
        raise ValueError(f"material head has {head.out_features} outputs, old list implies {len(old_ids) + 1}")
    if len(set(new_ids)) != len(new_ids) or not new_ids:
        raise ValueError("new material list must be non-empty and without duplicates")
    old_w, old_b = head.weight.detach(), head.bias.detach()
    old_index = {mid: i + 1 for i, mid in enumerate(old_ids)}
    weight = torch.empty(len(new_ids) + 1, head.in_features, dtype=old_w.dtype, device=old_w.device)
    bias = torch.empty(len(new_ids) + 1, dtype=old_b.dtype, device=old_b.device)
    weight[0], bias[0] = old_w[0], old_b[0]
    all_rows = list(old_index.values()) or [0]
    for row, mid in enumerate(new_ids, start=1):
        if mid in old_index:
            weight[row], bias[row] = old_w[old_index[mid]], old_b[old_index[mid]]
            continue
        rows = all_rows
        if substance_of is not None and mid in substance_of:
            same = [old_index[o] for o in old_ids if substance_of.get(o) == substance_of[mid]]
            rows = same or all_rows
        noise = torch.randn(head.in_features, generator=generator, dtype=old_w.dtype) * 0.01
        weight[row] = old_w[rows].mean(0) + noise.to(old_w.device)
        bias[row] = old_b[rows].mean()
    new_head = nn.Linear(head.in_features, len(new_ids) + 1).to(device=old_w.device, dtype=old_w.dtype)
    with torch.no_grad():
        new_head.weight.copy_(weight)
        new_head.bias.copy_(bias)
    model.fc_material = new_head
    model.num_materials = len(new_ids)
    return model
