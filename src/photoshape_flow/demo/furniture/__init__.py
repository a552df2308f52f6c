"""Seeded procedural seating: chairs, armchairs, office chairs, stools, benches and sofas.

A design is a flat dict of numbers and style choices (`design.sample_design`), built into named
object components with a semantic role (`kinds.build_components`), then grouped into *material
parts* the way real model files are (`segmentation.segment`), each with the flat material a
modeller would have left (`builtin`). Shapes are normalised into the unit cube of the mesh contract
(centred, longest side 1, +y up, front towards +z). `generate_furniture` runs these steps.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from photoshape_flow.demo.furniture.builtin import builtin_material
from photoshape_flow.demo.furniture.design import KIND_WEIGHTS, KINDS, sample_design
from photoshape_flow.demo.furniture.kinds import build_components
from photoshape_flow.demo.furniture.model import Furniture, FurniturePart
from photoshape_flow.demo.furniture.segmentation import SEGMENTATIONS, segment


def normalise(parts: list[FurniturePart]) -> None:
    """Move and scale all parts into the unit cube (centred, longest side 1), in place; UVs too."""
    allv = np.concatenate([c.piece.vertices for p in parts for c in p.components])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    centre = (lo + hi) / 2
    factor = 1.0 / float((hi - lo).max())
    for p in parts:
        for c in p.components:
            c.piece = c.piece.scaled(factor, centre)


def generate_furniture(
    rng: np.random.Generator,
    source_id: str,
    kind: str | None = None,
    design: dict[str, Any] | None = None,
    segmentation: str | None = None,
) -> Furniture:
    """One random shape (or the shape of a given design), segmented and normalised."""
    if design is None:
        if kind is None:
            kind = KINDS[int(rng.choice(len(KINDS), p=np.array(KIND_WEIGHTS) / sum(KIND_WEIGHTS)))]
        design = sample_design(rng, kind)
    if segmentation is None:
        segmentation = SEGMENTATIONS[int(rng.choice(3, p=[0.6, 0.2, 0.2]))]
    components = build_components(design)
    parts, segmentation = segment(components, segmentation, rng)
    for part in parts:
        part.builtin = builtin_material(rng, part)
    normalise(parts)
    return Furniture(source_id=source_id, kind=design["kind"], segmentation=segmentation, parts=parts, design=design)
