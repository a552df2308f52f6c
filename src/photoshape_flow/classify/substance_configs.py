"""Configurations of the substance network's training, importable without torch.

Profiles (`photoshape_flow.profiles`) nest a `SubstanceTrainConfig` per profile; the presets here are
the starting points they are built from: "tiny" (CI: a few iterations at 32 px), "cpu" (the demo:
128 px, 30 epochs; ~75 img/s on 2 idle cores) and "gpu" (192 px, width 32, 60 epochs, batch 64).
The device is always replaced by the resolved `settings.device` when training starts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

# the network family's name (classify/substance_net.py builds it); stored on the Classifier row
SUBSTANCE_ARCHITECTURE = "substance-unet-res"


@dataclass(frozen=True)
class SubstanceTrainConfig:
    preset: str = "cpu"
    # "unet": the from-scratch segmentation network; a backbone name ("efficientnet-lite0"): the part
    # recogniser (`classify.part_net`) trained on the bootstrap round's parts, its substance head read
    arch: str = "unet"
    size: int = 128
    width: int = 16
    epochs: int = 30
    batch_size: int = 16
    iters_per_epoch: int | None = None  # None: one pass over the training images
    lr: float = 2e-3
    min_lr_fraction: float = 0.05
    weight_decay: float = 1e-4
    crop_scale: tuple[float, float] = (0.55, 1.0)
    flip: bool = True
    jitter: float = 0.25
    blur: float = 0.0  # maximum Gaussian sigma (source pixels) of a random blur before the crop; 0: off
    frame_object: bool = False  # crop renders to the square around the object, as exemplars are cropped
    class_balance: bool = True
    # each part's pixels weigh (part area)^-part_balance in the loss (`substance_train.part_weights`);
    # 0: the plain per-pixel loss
    part_balance: float = 0.0
    # the side a whole image (a photo, a validation render) is read at; 0: `size`. Above `size` the
    # network trains on `size` crops cut from renders at this scale (`crop_scale` is then a fraction of
    # their area), so it learns parts at the finer pixel pitch it reads them at, for the same cost a step
    read_size: int = 0
    # 0: the run's seed (`PHOTOSHAPE_SEED`), as every other draw of a run; another value fixes this
    # network's own, so a second training on the same bootstrap renders is one `--set`
    seed: int = 0
    device: str = "cpu"

    @property
    def uses_backbone(self) -> bool:
        return self.arch != "unet"

    @property
    def read_side(self) -> int:
        """The side whole images are resized to before the network reads them."""
        return self.read_size or self.size

    @property
    def architecture(self) -> str:
        return f"{SUBSTANCE_ARCHITECTURE}-w{self.width}" if not self.uses_backbone else self.arch

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["crop_scale"] = list(self.crop_scale)
        if not self.uses_backbone:  # the segmentation network's rows (and hashes) stay as they were
            data.pop("arch")
        if not self.part_balance:
            data.pop("part_balance")
        if not self.read_size:
            data.pop("read_size")
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SubstanceTrainConfig:
        values = dict(data)
        if "crop_scale" in values:
            values["crop_scale"] = tuple(values["crop_scale"])
        known = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in values.items() if k in known})


PRESETS: dict[str, SubstanceTrainConfig] = {
    "tiny": SubstanceTrainConfig(preset="tiny", size=32, width=8, epochs=2, batch_size=4, iters_per_epoch=3),
    # every part the same weight in the loss (D70); "tiny" stays per-pixel, a smoke test of the plain loss
    "cpu": SubstanceTrainConfig(preset="cpu", size=128, width=16, epochs=30, batch_size=16, part_balance=1.0),
    "gpu": SubstanceTrainConfig(preset="gpu", size=192, width=32, epochs=60, batch_size=64, lr=3e-3, device="cuda",
                                part_balance=1.0),
    # the part recogniser: epochs of at most `iters_per_epoch` batches over the bootstrap round's parts
    "backbone": SubstanceTrainConfig(preset="backbone", arch="efficientnet-lite0", size=128, epochs=4,
                                     batch_size=32, iters_per_epoch=30, lr=1e-3),
    "backbone-tiny": SubstanceTrainConfig(preset="backbone-tiny", arch="efficientnet-lite0", size=32, epochs=1,
                                          batch_size=4, iters_per_epoch=2, lr=1e-3),
}


def read_side_of(config: Mapping[str, Any] | None) -> int | None:
    """The read side a stored network row's config names (`read_size`, else `size`); None if neither."""
    config = config or {}
    side = config.get("read_size") or config.get("size")
    return int(side) if side else None


def get_config(name: str, **overrides: Any) -> SubstanceTrainConfig:
    """A preset by name with field overrides (e.g. device resolved from settings)."""
    if name not in PRESETS:
        raise ValueError(f"unknown substance training preset {name!r}; choose from {sorted(PRESETS)}")
    return replace(PRESETS[name], **overrides)
