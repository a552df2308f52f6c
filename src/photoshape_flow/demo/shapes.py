"""The demo's shape collection and the held-out look-alikes only exemplars show, as OBJ + MTL files
with their ground-truth entries."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.demo.furniture import generate_furniture
from photoshape_flow.demo.furniture.design import KIND_WEIGHTS, KINDS, perturb_design
from photoshape_flow.demo.furniture.model import Furniture
from photoshape_flow.demo.obj import mtl_text, obj_text
from photoshape_flow.demo.seeding import child_rng
from photoshape_flow.demo.writing import sha256_hex, write_text

# First shapes cycle through the kinds so even tiny collections are varied.
KIND_CYCLE: tuple[str, ...] = ("chair", "office_chair", "sofa", "stool", "armchair", "bench")


def collection_shapes(seed: int, count: int) -> list[Furniture]:
    """The shape collection: shape_0000.. (kinds cycle first, then follow KIND_WEIGHTS)."""
    shapes = []
    weights = np.asarray(KIND_WEIGHTS) / sum(KIND_WEIGHTS)
    for k in range(count):
        rng = child_rng(seed, "shape", k)
        kind = KIND_CYCLE[k] if k < len(KIND_CYCLE) else KINDS[int(rng.choice(len(KINDS), p=weights))]
        shapes.append(generate_furniture(rng, f"shape_{k:04d}", kind=kind))
    return shapes


def heldout_shapes(seed: int, count: int, collection: list[Furniture]) -> list[tuple[Furniture, str]]:
    """Shapes only exemplars show: each a perturbed copy of a collection shape (returned with its id)."""
    out = []
    for k in range(count):
        rng = child_rng(seed, "heldout-shape", k)
        parent = collection[(k * 7 + int(rng.integers(len(collection)))) % len(collection)]
        design = perturb_design(rng, parent.design)
        out.append((generate_furniture(rng, f"heldout_{k:04d}", design=design), parent.source_id))
    return out


def write_shape(folder: Path, furniture: Furniture) -> tuple[Path, str]:
    """Write the shape's OBJ and MTL to `folder`; returns the OBJ path and the sha256 of its text."""
    stem = furniture.source_id
    text = obj_text(furniture, f"{stem}.mtl")
    write_text(folder / f"{stem}.mtl", mtl_text(furniture))
    write_text(folder / f"{stem}.obj", text)
    return folder / f"{stem}.obj", sha256_hex(text)


def shape_entry(furniture: Furniture, path: str, in_collection: bool, similar_to: str | None) -> dict[str, Any]:
    """The shape's entry in groundtruth.json (`shapes`): its kind, file, segmentation and parts."""
    return {
        "kind": furniture.kind,
        "in_collection": in_collection,
        "path": path,
        "segmentation": furniture.segmentation,
        "similar_to": similar_to,
        "parts": [{"index": i, "name": p.name, "roles": p.roles} for i, p in enumerate(furniture.parts, start=1)],
    }
