"""Per-part geometry as every exporter writes it: the renderer's texture coordinates baked in.

The UV transform of a part (texture-scale formula x 1/sqrt(D_i) x 1/material.scale, then the
`UVTransform` jitter; `photoshape_flow.render.specs.uv_matrix`) is *baked into the texcoords*
rather than expressed with KHR_texture_transform, because:

- every part already has its own vertex arrays, so baking is exact and costs nothing;
- it needs no extension, so viewers and importers that ignore KHR_texture_transform (OBJ has no
  equivalent at all, nor do PLY files for Mitsuba) show the same tiling the renderer used;
- tangents derived from the baked UVs (MikkTSpace in viewers) follow the jitter's rotation, so
  normal maps stay right; KHR_texture_transform rotations leave tangents unrotated in many viewers;
- one material shared by parts with different UV densities stays one material.

The raw UVs are recoverable: `assignment.json` records each part's D_i, material scale and jitter.

A material's `Refinement` UVs (`fit.refine`: a scale and rotation fitted to the photo) are baked
too where the format has no transform of its own (OBJ, PLY); the glTF writer keeps them out
(``bake_refinement=False``) and writes them as KHR_texture_transform (`khr_texture_transform`), with
the tangents still built from the refined UVs so normal maps turn with the texture.

Texture-space convention: `PartMesh.uvs` follow OBJ/OpenGL (v = 0 at the image's bottom row), and
so do `ExportPart.texcoords` (OBJ and PLY write them as they are). glTF puts v = 0 at the *top* row,
like Mitsuba's bitmap lookup, so the glTF writer flips v (`gltf_texcoords`), exactly as the
renderer does before handing UVs to Mitsuba (`render.scene.mitsuba_uvs`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from photoshape_flow.render.specs import apply_uv_matrix, refined_uv_matrix, uv_matrix


@dataclass
class ExportPart:
    """One part ready to write: float32 positions/normals/texcoords and uint32 triangle indices."""

    index: int
    name: str
    positions: np.ndarray
    normals: np.ndarray
    texcoords: np.ndarray
    faces: np.ndarray
    uv_matrix: np.ndarray


def gltf_texcoords(texcoords: np.ndarray) -> np.ndarray:
    """OBJ/OpenGL texcoords (v up) -> glTF/Mitsuba texcoords (v = 0 at the image's top row)."""
    out = np.array(texcoords, np.float32, copy=True)
    out[:, 1] = 1.0 - out[:, 1]
    return out


def unit_normals(normals: np.ndarray, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Normalised per-vertex normals; zero or non-finite ones are rebuilt from the adjacent faces."""
    n = np.nan_to_num(np.asarray(normals, np.float64).reshape(-1, 3), nan=0.0, posinf=0.0, neginf=0.0)
    if n.shape[0] != len(positions):
        n = np.zeros((len(positions), 3))
    length = np.linalg.norm(n, axis=1)
    bad = length < 1e-8
    if bad.any() and len(faces):
        v = np.asarray(positions, np.float64)
        f = np.asarray(faces, np.int64)
        face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        acc = np.zeros_like(v)
        for k in range(3):
            np.add.at(acc, f[:, k], face_n)
        n[bad] = acc[bad]
        length = np.linalg.norm(n, axis=1)
        bad = length < 1e-12
    n[bad] = (0.0, 1.0, 0.0)
    length[bad] = 1.0
    return (n / length[:, None]).astype(np.float32)


def khr_texture_transform(scale: float, rotation: float) -> dict[str, Any]:
    """KHR_texture_transform of a refinement's uv' = R(rotation) @ (scale * uv) (OBJ UVs, v up) on glTF UVs.

    glTF flips v (v' = 1 - v), and the extension computes T(offset) R(r) S(scale) with R(r) =
    [[cos r, -sin r], [sin r, cos r]] on the flipped UVs; conjugating by the flip turns the rotation
    the other way and moves the origin: r = -rotation, offset = (-s sin, 1 - s cos).
    """
    c, s = math.cos(rotation), math.sin(rotation)
    return {"offset": [round(-scale * s, 9), round(1.0 - scale * c, 9)], "rotation": round(-rotation, 9),
            "scale": [round(scale, 9), round(scale, 9)]}


def export_parts(
    shape: Any, materials: Sequence[Any] | None = None, uv_transforms: Sequence[Any] | None = None,
    bake_refinement: bool = True,
) -> list[ExportPart]:
    """Parts of `shape` with baked texcoords; `materials[i]` / `uv_transforms[i]` belong to `shape.parts[i]`.

    A part whose material is None (built-in) or has ``scale=None`` keeps its mesh UVs (plus jitter).
    Parts without faces are left out (glTF forbids empty accessors).
    """
    n = len(shape.parts)
    materials = list(materials) if materials is not None else [None] * n
    jitters = list(uv_transforms) if uv_transforms is not None else [None] * n
    if len(materials) != n or len(jitters) != n:
        raise ValueError(f"shape has {n} parts but got {len(materials)} materials and {len(jitters)} UV transforms")
    out: list[ExportPart] = []
    for part, spec, jitter in zip(shape.parts, materials, jitters, strict=True):
        faces = np.asarray(part.faces, np.int64).reshape(-1, 3)
        if len(faces) == 0:
            continue
        positions = np.asarray(part.vertices, np.float32).reshape(-1, 3)
        if faces.min() < 0 or faces.max() >= len(positions):
            raise ValueError(f"part {part.index} ({part.name}): face index out of range")
        matrix = refined_uv_matrix(part.uv_density, spec, jitter) if bake_refinement else uv_matrix(
            part.uv_density, None if spec is None else getattr(spec, "scale", None), jitter)
        uvs = np.asarray(part.uvs, np.float32).reshape(-1, 2)
        if len(uvs) != len(positions):
            uvs = np.zeros((len(positions), 2), np.float32)
        out.append(
            ExportPart(
                index=int(part.index),
                name=str(part.name),
                positions=positions,
                normals=unit_normals(part.normals, positions, faces),
                texcoords=apply_uv_matrix(uvs, matrix),
                faces=faces.astype(np.uint32),
                uv_matrix=matrix,
            )
        )
    return out


def tangents(positions: np.ndarray, normals: np.ndarray, texcoords: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-vertex tangents (N, 4): xyz = dP/du accumulated over the adjacent triangles,
    Gram-Schmidt-orthogonalised against the normal; w = +-1 the bitangent's handedness.

    Give OpenGL-convention (v up) texcoords: the bitangent cross(N, T) * w then points to the top
    of the image, the +Y (green) direction of an OpenGL normal map, as glTF viewers expect.

    This is the frame Mitsuba's `normalmap` BSDF builds from the UVs (dp/du), so a normal map looks
    the same in a glTF viewer as in the renderer; vertices without a usable UV gradient get any
    unit vector perpendicular to the normal.
    """
    p = np.asarray(positions, np.float64)
    uv = np.asarray(texcoords, np.float64)
    n = np.asarray(normals, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    e1, e2 = p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]
    d1, d2 = uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    dpdv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    t_acc, b_acc = np.zeros_like(p), np.zeros_like(p)
    for k in range(3):
        np.add.at(t_acc, f[:, k], dpdu)
        np.add.at(b_acc, f[:, k], dpdv)
    t = t_acc - n * np.sum(t_acc * n, axis=1, keepdims=True)
    length = np.linalg.norm(t, axis=1)
    bad = length < 1e-12
    if bad.any():  # any perpendicular: cross with the axis least aligned with the normal
        axis = np.eye(3)[np.argmin(np.abs(n[bad]), axis=1)]
        t[bad] = np.cross(n[bad], axis)
        length[bad] = np.linalg.norm(t[bad], axis=1)
    t /= length[:, None]
    w = np.where(np.sum(np.cross(n, t) * b_acc, axis=1) < 0.0, -1.0, 1.0)
    return np.concatenate([t, w[:, None]], axis=1).astype(np.float32)
