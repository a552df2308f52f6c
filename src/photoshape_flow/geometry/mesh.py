"""The preprocessed shape as the pipeline stores it: one triangle mesh per material part.

Conventions (used by ingest, the renderer, alignment and export alike):

- Coordinates are in the *unit cube*: the whole shape's bounding box is centred at the origin and
  its longest side is 1, so every vertex lies in [-0.5, 0.5]^3. +y is up; the shape's front faces +z
  when the source says so (ShapeNet and Sweet Home 3D do).
- Parts are numbered from 1 in the order stored; 0 is the background in part-ID maps.
- Each part has its own vertex arrays (UV seams split vertices), smooth per-vertex normals, and UVs
  in texture units (one unit = one texture tile before the texture-scale formula).
- `uv_density` is D_i = A_uv / A_world of section 5.1; the renderer multiplies UVs by
  1 / sqrt(D_i) / material_scale so a texture tile covers `material_scale` world units.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class PartMesh:
    """One material part: a triangle mesh with normals and UVs."""

    index: int
    name: str
    vertices: np.ndarray  # (n, 3) float32, unit-cube coordinates
    faces: np.ndarray  # (m, 3) int32
    normals: np.ndarray  # (n, 3) float32, unit length
    uvs: np.ndarray  # (n, 2) float32
    builtin_material: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def area_world(self) -> float:
        return float(triangle_areas(self.vertices, self.faces).sum())

    @property
    def area_uv(self) -> float:
        uv3 = np.concatenate([self.uvs, np.zeros((len(self.uvs), 1), self.uvs.dtype)], axis=1)
        return float(triangle_areas(uv3, self.faces).sum())

    @property
    def uv_density(self) -> float:
        """D_i = A_uv / A_world; 1.0 for a degenerate part so callers never divide by zero."""
        world = self.area_world
        uv = self.area_uv
        if world <= 0 or uv <= 0:
            return 1.0
        return uv / world


@dataclass
class ShapeMesh:
    """A preprocessed shape: its parts in the unit cube."""

    parts: list[PartMesh]
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def num_vertices(self) -> int:
        return int(sum(len(p.vertices) for p in self.parts))

    @property
    def num_faces(self) -> int:
        return int(sum(len(p.faces) for p in self.parts))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        allv = np.concatenate([p.vertices for p in self.parts], axis=0)
        return allv.min(axis=0), allv.max(axis=0)

    def part(self, index: int) -> PartMesh:
        for p in self.parts:
            if p.index == index:
                return p
        raise KeyError(f"shape has no part {index}")

    # -- serialisation (the `shape.mesh_blob` format) ------------------------------------------
    def to_npz_bytes(self) -> bytes:
        """Serialise to a compressed .npz; stable bytes for equal content (content-addressed)."""
        arrays: dict[str, np.ndarray] = {}
        header = {"meta": self.meta, "parts": []}
        for p in self.parts:
            k = f"p{p.index}"
            arrays[f"{k}_vertices"] = np.asarray(p.vertices, np.float32)
            arrays[f"{k}_faces"] = np.asarray(p.faces, np.int32)
            arrays[f"{k}_normals"] = np.asarray(p.normals, np.float32)
            arrays[f"{k}_uvs"] = np.asarray(p.uvs, np.float32)
            header["parts"].append(
                {"index": p.index, "name": p.name, "builtin_material": p.builtin_material, "meta": p.meta}
            )
        arrays["header"] = np.frombuffer(json.dumps(header, sort_keys=True).encode(), dtype=np.uint8)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        return buffer.getvalue()

    @classmethod
    def from_npz_bytes(cls, data: bytes) -> ShapeMesh:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            header = json.loads(npz["header"].tobytes().decode())
            parts = [
                PartMesh(
                    index=int(h["index"]),
                    name=str(h["name"]),
                    vertices=npz[f"p{h['index']}_vertices"],
                    faces=npz[f"p{h['index']}_faces"],
                    normals=npz[f"p{h['index']}_normals"],
                    uvs=npz[f"p{h['index']}_uvs"],
                    builtin_material=h.get("builtin_material") or {},
                    meta=h.get("meta") or {},
                )
                for h in header["parts"]
            ]
        return cls(parts=parts, meta=header.get("meta") or {})


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each triangle (works for 3D positions; pad 2D UVs with a zero column)."""
    if len(faces) == 0:
        return np.zeros(0, np.float64)
    v = np.asarray(vertices, np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
