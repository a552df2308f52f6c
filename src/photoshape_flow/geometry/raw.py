"""A shape as read from its source file, before preprocessing: material groups with raw arrays.

Readers (OBJ, glTF) produce a `RawShape`; `geometry.preprocess` turns it into the `ShapeMesh` of the
mesh contract. Keeping the two apart lets every reader share one cleaning and normalisation path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


class BadShapeError(ValueError):
    """The input cannot become a shape (corrupt, empty, non-finite, over a limit): reject it."""


class ShapeTooLargeError(BadShapeError):
    """The shape exceeds a configured limit (faces, bytes)."""


@dataclass
class RawMaterial:
    """A part's built-in material as the source describes it (MTL or glTF PBR)."""

    name: str
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)  # sRGB 0..1
    roughness: float = 1.0
    metallic: float = 0.0
    texture_path: Path | None = None  # OBJ: map_Kd on disk
    texture_image: Any = None  # glTF: decoded PIL image or ndarray
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class RawPart:
    """One material group: positions, triangles and optional source UVs (shared indexing)."""

    name: str
    vertices: np.ndarray  # (n, 3) float64, source coordinates
    faces: np.ndarray  # (m, 3) int64
    uvs: np.ndarray | None  # (n, 2) float64 or None when the source has none for this group
    material: RawMaterial
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass
class RawShape:
    parts: list[RawPart]
    meta: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    @property
    def num_faces(self) -> int:
        return int(sum(len(p.faces) for p in self.parts))
