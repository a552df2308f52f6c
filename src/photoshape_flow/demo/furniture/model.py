"""What a generated piece of seating is made of: components, material parts and the whole shape.

A component is one named object group with a semantic role; a material part groups components the
way a modeller's `usemtl` groups do; `Furniture` holds the parts in file order and converts to the
`ShapeMesh` ingest will produce from its OBJ.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from photoshape_flow.demo.primitives import Piece, merge_pieces
from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh

ROLES: tuple[str, ...] = ("legs", "seat", "back", "arms", "cushion", "frame", "base", "casters")

# Which substances a part of each role plausibly has (hard / upholstered), for built-in colours here
# and for the exemplar material prior in `exemplars`.
SUBSTANCE_PRIOR: dict[str, dict[str, float]] = {
    "legs": {"wood": 0.5, "metal": 0.4, "plastic": 0.1},
    "frame": {"wood": 0.55, "metal": 0.35, "plastic": 0.1},
    "seat": {"wood": 0.6, "plastic": 0.4},
    "back": {"wood": 0.6, "plastic": 0.4},
    "arms": {"wood": 0.6, "metal": 0.2, "plastic": 0.2},
    "base": {"metal": 0.6, "plastic": 0.4},
    "casters": {"plastic": 1.0},
    "soft": {"fabric": 0.55, "leather": 0.45},
}


@dataclass
class Component:
    """One object group (`g` in OBJ): a named piece with a semantic role."""

    name: str
    role: str
    piece: Piece
    soft: bool = False  # upholstered (fabric or leather in real life)
    unit: str = ""  # components with the same unit (a caster's wheel and fork) stay together when split


@dataclass
class FurniturePart:
    """One material part (`usemtl` group) made of one or more components."""

    name: str
    components: list[Component]
    builtin: dict[str, Any] = field(default_factory=dict)

    @property
    def roles(self) -> list[str]:
        return sorted({c.role for c in self.components})

    @property
    def soft(self) -> bool:
        return any(c.soft for c in self.components)

    @property
    def prior_key(self) -> str:
        """The key of SUBSTANCE_PRIOR that describes this part's plausible substances."""
        if self.soft:
            return "soft"
        counts: dict[str, float] = {}
        for c in self.components:
            counts[c.role] = counts.get(c.role, 0.0) + float(len(c.piece.faces))
        role = max(sorted(counts), key=lambda r: counts[r])
        return role if role in SUBSTANCE_PRIOR else "frame"


@dataclass
class Furniture:
    """A generated shape: parts in file order, already in the unit cube."""

    source_id: str
    kind: str
    segmentation: str
    parts: list[FurniturePart]
    design: dict[str, Any]

    def to_shape_mesh(self) -> ShapeMesh:
        """The in-memory ShapeMesh that ingest will produce from the OBJ (same part numbering)."""
        parts = []
        for i, part in enumerate(self.parts, start=1):
            piece = merge_pieces([c.piece for c in part.components])
            parts.append(
                PartMesh(
                    index=i,
                    name=part.name,
                    vertices=piece.vertices.astype(np.float32),
                    faces=piece.faces.astype(np.int32),
                    normals=piece.normals.astype(np.float32),
                    uvs=piece.uvs.astype(np.float32),
                    builtin_material=dict(part.builtin),
                    meta={"roles": part.roles, "groups": [c.name for c in part.components]},
                )
            )
        return ShapeMesh(
            parts=parts,
            meta={"source_id": self.source_id, "kind": self.kind, "segmentation": self.segmentation, "source": "demo"},
        )
