"""Named training configurations of the material classifier.

* ``tiny``: CI and unit tests. ResNet-18 at width 8 (same keys, 1/64 of the compute), 32 px, a few
  steps. Learns colour-coded toy data; not a real classifier.
* ``cpu``: the demo. ResNet-18 (full width) at 96 px, Adam 1e-3, 6 epochs of at most 30 batches of 32
  (at most 5,760 region views: ~1.5 min on 2 idle cores; bench/classifier.py measures it). Raise
  ``epochs`` / ``max_steps_per_epoch``
  for the medium demo. Torch threads above the free cores are ruinous (OpenMP spinning: 20x slower
  under load), so set ``PHOTOSHAPE_TORCH_THREADS`` when training shares the box. From scratch: no ImageNet
  weights ship with the project, and SGD at the paper's 1e-4 barely moves a randomly initialised
  network in that budget, hence Adam with a larger step, decayed along a cosine (per step) so the
  last epochs settle instead of oscillating, and the epoch with the best validation mtl@1 is the
  one kept; hue jitter is +-0.02 of a turn, below the colour differences between the demo's
  materials of one substance (docs/decisions.md, D2). ``finetune_epochs`` is used when the material
  set grew and training starts from the previous classifier.

``frame_object`` (cut each training render to the square around its object, as exemplars are cut)
and ``augment.blur`` (a random blur against the renders' sampling noise) stay off in every
configuration: together they measured worse on the exemplars (docs/decisions.md, D4).
* ``backbone``: the part recogniser (`classify.part_net`): ImageNet EfficientNet-Lite0 over a 160 px
  crop of the part, stages 4-7 fine-tuned at a tenth of the heads' step, photo-like augmentation
  (white balance, blur, noise, JPEG) on top of the geometric and colour ones (docs/decisions.md, D53).
* ``paper``: section 5.2 as published. ResNet-34 at 224 px, SGD with a fixed learning rate of 1e-4,
  momentum 0.9, weight decay 1e-4 (never on the log-variances), uncertainty-weighted loss with
  s_m = 0, s_s = -1, about 100 epochs, the last epoch kept; ImageNet weights when `pretrained` names a torchvision
  ``resnet34`` .pth file (the paper starts from ImageNet, then OpenSurfaces substance pretraining,
  which is not reproduced). Meant for CUDA (`settings.device` = auto picks it when present); on the
  2-core CPU one epoch over 10k regions is ~17 min (bench/classifier.py; docs/benchmarks.md).

Profiles (`photoshape_flow.profiles`) nest these as `Profile.training`. `get_config(name, **overrides)`
returns a frozen dataclass; `config_hash` is the part of the
classifier's params_hash that depends on the configuration.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class AugmentConfig:
    """Ranges of the random augmentations of `classify.augment` (defaults near the original code's
    torchvision settings); here, beside the classifier configs, so profiles load without torch."""

    enabled: bool = True
    rotation_deg: float = 10.0
    crop_scale: tuple[float, float] = (0.5, 1.0)
    aspect_ratio: tuple[float, float] = (3 / 4, 4 / 3)
    hflip: bool = True
    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    hue: float = 0.05  # fraction of a full turn of the hue circle
    blur: float = 0.0  # maximum Gaussian sigma in source pixels (0: off, as in the paper)
    # photo-like degradations (0: off, as in the paper): what a product photo shows and a clean render not
    white_balance: float = 0.0  # std of the log gain per channel (a camera's white balance)
    tone: float = 0.0  # std of the log exponent of a random gamma curve (another camera's or renderer's tone)
    noise: float = 0.0  # maximum sensor-noise sigma, in 8-bit levels
    jpeg_quality: int = 0  # lowest JPEG quality drawn (up to 95); 0: never compressed
    min_mask_kept: float = 0.25
    max_tries: int = 4


HEADS = ("heads", "descriptor")


@dataclass(frozen=True)
class ClassifierConfig:
    name: str
    arch: str = "resnet18"
    width: int = 64
    image_size: int = 96
    batch_size: int = 32
    epochs: int = 6
    finetune_epochs: int = 2
    max_steps_per_epoch: int | None = None  # cap on batches per epoch (a random subset when data is larger)
    optimizer: str = "sgd"  # sgd | adam
    lr: float = 1e-4
    lr_schedule: str = "constant"  # constant (the paper) | cosine (per step, down to lr * lr_floor)
    lr_floor: float = 0.02
    select_metric: str | None = None  # keep the epoch with the best validation value of this metric
    momentum: float = 0.9
    weight_decay: float = 1e-4
    loss_mode: str = "uncertainty"  # uncertainty | fixed
    material_weight: float = 1.0
    substance_weight: float = 1.0  # 0 disables the substance task
    init_log_var_material: float = 0.0
    init_log_var_substance: float = -1.0
    pretrained: str | None = None  # torchvision-format ImageNet .pth (RGB filters of conv1 + backbone)
    min_region_fraction: float = 0.005
    background_every: int = 4  # one background example per n renderings (0: none)
    frame_object: bool = False  # crop renders to the square around the object, as exemplars are cropped
    val_fraction: float = 0.1  # held out by key hash when no rendering has split "val"
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    eval_batch_size: int = 64
    num_workers: int = 0
    channels_last: bool = False
    seed: int = 0
    # the part recogniser (arch "efficientnet-lite0" / "efficientnet-lite2", `classify.part_net`) only
    crop_size: int = 160  # the part crop's side as the backbone reads it
    crop_context: float = 0.25  # context around the part's bounding box, a fraction of its side
    isolate_part: bool = True  # paint pixels outside the part white before the backbone
    train_from_stage: int = 4  # stages below stay frozen at their ImageNet weights
    backbone_lr_scale: float = 0.1  # step of the fine-tuned blocks relative to the new heads
    # "heads": the paper's linear material and substance heads; "descriptor": the material head is a
    # shared photo/material descriptor with each material the mean of its renders' (`classify.descriptor`)
    head: str = "heads"

    def __post_init__(self) -> None:
        if self.head not in HEADS:
            raise ValueError(f"head: {self.head!r} is not one of {', '.join(HEADS)}")

    def check(self) -> None:
        """Raise ValueError for fields that contradict each other (checked once all are set)."""
        if self.head != "heads" and not self.uses_backbone:
            raise ValueError(f"head {self.head!r} needs a pretrained backbone arch (efficientnet-lite*), "
                             f"not {self.arch!r}")
        if self.finetune_epochs < 1 and self.head != "descriptor":
            raise ValueError("finetune_epochs 0 (new materials read from their renders, no training) needs "
                             "head 'descriptor'")

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["augment"] = dataclasses.asdict(self.augment)
        return json.loads(json.dumps(data))  # tuples -> lists: a plain-JSON dict

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ClassifierConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in data.items() if k in known}
        aug = dict(values.get("augment") or {})
        for key in ("crop_scale", "aspect_ratio"):
            if key in aug:
                aug[key] = tuple(aug[key])
        values["augment"] = AugmentConfig(**aug)
        return cls(**values)

    def replace(self, **changes: Any) -> ClassifierConfig:
        return dataclasses.replace(self, **changes)

    @property
    def uses_backbone(self) -> bool:
        """True for the part recogniser on a pretrained backbone (`classify.part_net`)."""
        return self.arch.startswith("efficientnet-lite")

    @property
    def architecture(self) -> str:
        if self.uses_backbone:
            return f"{self.arch}-{'desc' if self.head == 'descriptor' else 'part'}{self.crop_size}"
        return self.arch if self.width == 64 else f"{self.arch}-w{self.width}"


CONFIGS: dict[str, ClassifierConfig] = {
    "tiny": ClassifierConfig(
        name="tiny",
        arch="resnet18",
        width=8,
        image_size=32,
        batch_size=8,
        epochs=2,
        finetune_epochs=1,
        max_steps_per_epoch=3,
        optimizer="adam",
        lr=3e-3,
        weight_decay=0.0,
        background_every=0,
        augment=AugmentConfig(rotation_deg=5.0, crop_scale=(0.7, 1.0)),
        eval_batch_size=32,
    ),
    "cpu": ClassifierConfig(
        name="cpu",
        arch="resnet18",
        width=64,
        image_size=96,
        batch_size=32,
        epochs=6,
        finetune_epochs=2,
        max_steps_per_epoch=30,
        optimizer="adam",
        lr=1e-3,
        lr_schedule="cosine",
        select_metric="mtl@1",
        weight_decay=1e-4,
        augment=AugmentConfig(hue=0.02, saturation=0.15),
        eval_batch_size=64,
    ),
    "backbone": ClassifierConfig(
        name="backbone",
        arch="efficientnet-lite0",
        image_size=128,  # the frame's scale: a photo's part keeps about a render part's pixel count
        crop_size=160,
        batch_size=32,
        epochs=6,
        finetune_epochs=2,
        max_steps_per_epoch=30,
        optimizer="adam",
        lr=1e-3,
        backbone_lr_scale=0.1,
        lr_schedule="cosine",
        select_metric="mtl@1",
        weight_decay=1e-4,
        augment=AugmentConfig(hue=0.02, saturation=0.15, blur=1.0, white_balance=0.05, noise=3.0,
                              jpeg_quality=70),
        eval_batch_size=64,
    ),
    "paper": ClassifierConfig(
        name="paper",
        arch="resnet34",
        width=64,
        image_size=224,
        batch_size=64,
        epochs=100,
        finetune_epochs=10,
        optimizer="sgd",
        lr=1e-4,
        momentum=0.9,
        weight_decay=1e-4,
        eval_batch_size=128,
        num_workers=4,
        channels_last=True,
    ),
}


def get_config(name: str = "cpu", **overrides: Any) -> ClassifierConfig:
    """A named configuration, with fields overridden (e.g. ``pretrained="resnet34.pth"``)."""
    if name not in CONFIGS:
        raise ValueError(f"unknown classifier config {name!r}; expected one of {sorted(CONFIGS)}")
    return CONFIGS[name].replace(**overrides) if overrides else CONFIGS[name]


_RECOGNISER_FIELDS = ("crop_size", "crop_context", "isolate_part", "train_from_stage", "backbone_lr_scale")
_PHOTO_AUGMENT_FIELDS = ("white_balance", "noise", "jpeg_quality")


def config_hash(config: ClassifierConfig) -> str:
    """sha256 of the configuration fields that change the trained model."""
    data = config.to_dict()
    for key in ("eval_batch_size", "num_workers"):  # do not change the result
        data.pop(key, None)
    # fields added with the part recogniser count only where they act, so the ResNet configurations
    # (and every classifier trained with them) keep their hashes
    if not config.uses_backbone:
        for key in _RECOGNISER_FIELDS:
            data.pop(key, None)
    if config.head == "heads":  # added with the descriptor: the two-head networks keep their hashes
        data.pop("head", None)
    for key in _PHOTO_AUGMENT_FIELDS:
        if not data["augment"].get(key):
            data["augment"].pop(key, None)
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()
