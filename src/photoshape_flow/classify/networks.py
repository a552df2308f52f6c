"""The material classifier's network families, built from a training config or a checkpoint's spec.

Three networks share one contract (RGB + mask in, material and substance logits out): the paper's
ResNet over the whole frame (`classify.resnet`, trained from scratch or from a torchvision file), the
part recogniser on a pretrained EfficientNet-Lite (`classify.part_net`) and the same encoder as a
shared photo/material descriptor (`classify.descriptor`). The training loop, checkpoints and inference
only see `MaterialNetwork`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch

from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.classify.descriptor import MaterialDescriptor
from photoshape_flow.classify.part_net import PartRecognizer
from photoshape_flow.classify.resnet import ARCHITECTURES, MaterialResNet, build_model, grow_material_head

MaterialNetwork = MaterialResNet | PartRecognizer | MaterialDescriptor


def build_network(config: ClassifierConfig, num_materials: int, *, seed: int | None = None) -> MaterialNetwork:
    """A fresh network for `config`: ImageNet weights for a backbone arch, else `resnet.build_model`."""
    config.check()
    if not config.uses_backbone:
        return build_model(config.arch, num_materials, width=config.width, pretrained=config.pretrained, seed=seed)
    with torch.random.fork_rng(devices=[]):  # seed the new heads without touching the global RNG
        if seed is not None:
            torch.manual_seed(seed)
        family = MaterialDescriptor if config.head == "descriptor" else PartRecognizer
        return family(config.arch, num_materials, crop_size=config.crop_size, context=config.crop_context,
                      isolate=config.isolate_part, train_from_stage=config.train_from_stage)


def network_from_spec(spec: dict[str, Any]) -> MaterialNetwork:
    """The (untrained) network a checkpoint's ``model_spec`` describes; its state dict loads next."""
    if spec.get("arch") in ARCHITECTURES:
        return MaterialResNet(**spec)
    if spec.get("head") == "descriptor":
        return MaterialDescriptor(**{k: v for k, v in spec.items() if k != "head"}, pretrained=False)
    return PartRecognizer(**spec, pretrained=False)


def grow_materials(model: MaterialNetwork, old_ids: Sequence[int], new_ids: Sequence[int],
                   substance_of: Mapping[int, str] | None, generator: torch.Generator | None = None) -> MaterialNetwork:
    """Re-map a trained network's material outputs to a grown material list (fine-tuning after new
    materials): the descriptor re-maps its proxies and prototypes, the linear heads their rows."""
    if isinstance(model, MaterialDescriptor):
        return model.grow_materials(old_ids, new_ids, substance_of)
    return grow_material_head(model, old_ids, new_ids, substance_of, generator=generator)
