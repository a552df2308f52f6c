"""Small analytic shapes in the mesh contract (used for material previews and tests)."""

from __future__ import annotations

from typing import Any

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh


def uv_sphere(segments: int = 64, rings: int = 32, name: str = "sphere") -> ShapeMesh:
    """A unit-cube sphere (radius 0.5) with latitude/longitude UVs in [0, 1] and exact normals."""
    theta = np.linspace(0.0, np.pi, rings + 1)  # polar angle from +y
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1).reshape(-1, 3)
    uvs = np.stack([p / (2.0 * np.pi), 1.0 - t / np.pi], axis=-1).reshape(-1, 2)
    idx = np.arange((rings + 1) * (segments + 1)).reshape(rings + 1, segments + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    v = 0.5 * normals
    area = 0.5 * np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1)
    faces = faces[area > 1e-12]
    builtin: dict[str, Any] = {"albedo": [0.8, 0.8, 0.8], "roughness": 0.5, "metallic": 0.0, "name": name}
    part = PartMesh(index=1, name=name, vertices=v.astype(np.float32), faces=faces.astype(np.int32),
                    normals=normals.astype(np.float32), uvs=uvs.astype(np.float32), builtin_material=builtin)
    return ShapeMesh(parts=[part], meta={"primitive": "uv_sphere"})
