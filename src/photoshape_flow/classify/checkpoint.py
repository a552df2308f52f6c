"""Classifier checkpoints as bytes: everything to resume training or to run inference.

A checkpoint is a plain dict saved with `torch.save` and read back with ``weights_only=True``
(tensors, numbers, strings, lists and dicts only, so loading one never runs code):

* ``format``, ``kind`` ("material"), ``model_spec`` (the network's constructor arguments, `classify.networks`),
  ``model`` (state dict), ``materials`` (material ids in head order, without background),
  ``material_substances`` (substance name per material), ``image_size``, ``config`` (the training
  config as a dict), ``epoch`` (epochs completed), ``history`` (per-epoch metrics);
* for resuming also ``optimizer``, ``loss`` (the log-variances) and ``rng`` (torch RNG state).
  `slim` drops those three for the final, inference-only blob.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from photoshape_flow.classify.networks import MaterialNetwork, network_from_spec

FORMAT = 1
RESUME_KEYS = ("optimizer", "loss", "rng")


def make_checkpoint(
    model: MaterialNetwork,
    *,
    materials: Sequence[int],
    material_substances: Sequence[str],
    image_size: int,
    config: dict[str, Any],
    epoch: int,
    history: list[dict[str, Any]] | None = None,
    optimizer: torch.optim.Optimizer | None = None,
    loss: torch.nn.Module | None = None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    if len(materials) != model.num_materials or len(material_substances) != len(materials):
        raise ValueError("materials, material_substances and the material head disagree in length")
    checkpoint: dict[str, Any] = {
        "format": FORMAT,
        "kind": "material",
        "model_spec": model.spec(),
        "model": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        "materials": [int(m) for m in materials],
        "material_substances": list(material_substances),
        "image_size": int(image_size),
        "config": dict(config),
        "epoch": int(epoch),
        "history": list(history or []),
    }
    if optimizer is not None:
        checkpoint["optimizer"] = _to_cpu(optimizer.state_dict())
    if loss is not None:
        checkpoint["loss"] = {k: v.detach().cpu().clone() for k, v in loss.state_dict().items()}
    checkpoint["rng"] = {"torch": torch.get_rng_state()}
    if extra:
        checkpoint["extra"] = dict(extra)
    return checkpoint


def _to_cpu(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().clone()
    if isinstance(value, dict):
        return {k: _to_cpu(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_to_cpu(v) for v in value)
    return value


def slim(checkpoint: dict[str, Any]) -> dict[str, Any]:
    """The checkpoint without optimizer, loss and RNG state (inference and fine-tuning only)."""
    return {k: v for k, v in checkpoint.items() if k not in RESUME_KEYS}


def to_bytes(checkpoint: dict[str, Any]) -> bytes:
    buffer = io.BytesIO()
    torch.save(checkpoint, buffer)
    return buffer.getvalue()


def load(source: bytes | str | Path) -> dict[str, Any]:
    """A checkpoint from bytes or a file path, tensors on the CPU; safe (weights_only) unpickling."""
    handle: Any = io.BytesIO(source) if isinstance(source, bytes | bytearray) else Path(source)
    try:
        checkpoint = torch.load(handle, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for corrupt or foreign files
        where = "checkpoint bytes" if isinstance(source, bytes | bytearray) else str(source)
        raise ValueError(f"{where}: not a readable classifier checkpoint ({exc.__class__.__name__})") from exc
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != FORMAT or "model_spec" not in checkpoint:
        raise ValueError("not a photoshape_flow material classifier checkpoint (format 1)")
    return checkpoint


def build_model(checkpoint: dict[str, Any]) -> MaterialNetwork:
    """The network of a checkpoint with its weights loaded (train mode; callers pick eval)."""
    model = network_from_spec(checkpoint["model_spec"])
    model.load_state_dict(checkpoint["model"])
    return model
