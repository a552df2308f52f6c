"""The material classifier's network families, built from a training config or a checkpoint's spec.

Two families share one contract (RGB + mask in, material and substance logits out): the paper's
ResNet over the whole frame (`classify.resnet`, trained from scratch or from a torchvision file) and
the part recogniser on a pretrained EfficientNet-Lite (`classify.part_net`). The training loop,
checkpoints and inference only see `MaterialNetwork`.
"""

from __future__ import annotations

from typing import Any

import torch

from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.classify.part_net import PartRecognizer
from photoshape_flow.classify.resnet import ARCHITECTURES, MaterialResNet, build_model

MaterialNetwork = MaterialResNet | PartRecognizer


def build_network(config: ClassifierConfig, num_materials: int, *, seed: int | None = None) -> MaterialNetwork:
    """A fresh network for `config`: ImageNet weights for a backbone arch, else `resnet.build_model`."""
    if not config.uses_backbone:
        return build_model(config.arch, num_materials, width=config.width, pretrained=config.pretrained, seed=seed)
    with torch.random.fork_rng(devices=[]):  # seed the new heads without touching the global RNG
        if seed is not None:
            torch.manual_seed(seed)
        return PartRecognizer(config.arch, num_materials, crop_size=config.crop_size, context=config.crop_context,
                              isolate=config.isolate_part, train_from_stage=config.train_from_stage)


def network_from_spec(spec: dict[str, Any]) -> MaterialNetwork:
    """The (untrained) network a checkpoint's ``model_spec`` describes; its state dict loads next."""
    if spec.get("arch") in ARCHITECTURES:
        return MaterialResNet(**spec)
    return PartRecognizer(**spec, pretrained=False)
