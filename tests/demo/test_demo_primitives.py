"""Primitives are closed, outward-facing solids with world-unit UVs (density ~1)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from photoshape_flow.demo.primitives import (
    box,
    cylinder,
    merge_pieces,
    rotation_x,
    rounded_box,
    rounded_path,
    tapered_box,
    tube,
)
from photoshape_flow.geometry.mesh import triangle_areas

PIECES = {
    "box": lambda: box([0.1, 0.2, 0.3], [0.4, 0.2, 0.1], rotation_x(0.3)),
    "tapered_box": lambda: tapered_box([0, 0, 0], [0.05, 0.5, 0.02], [0.02, 0.02], [0.04, 0.04]),
    "rounded_box": lambda: rounded_box([0, 0.3, 0], [0.5, 0.1, 0.4], 0.03),
    "cylinder": lambda: cylinder([0, 0, 0], [0.1, 0.5, 0.05], 0.03, 0.02),
    "tube": lambda: tube(rounded_path(np.array([[0, 0.4, 0], [0, 0, 0], [0.4, 0, 0], [0.4, 0.4, 0]]), 0.1), 0.015),
}


def _welded(piece) -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(piece.vertices, piece.faces, process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return mesh


@pytest.mark.parametrize("name", sorted(PIECES))
def test_primitive_is_closed_outward_and_uv_uniform(name: str) -> None:
    piece = PIECES[name]()
    mesh = _welded(piece)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward winding
    v, f = piece.vertices, piece.faces
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert ((face_n * piece.normals[f].sum(axis=1)).sum(axis=1) > 0).all()  # normals agree with winding
    np.testing.assert_allclose(np.linalg.norm(piece.normals, axis=1), 1.0, atol=1e-6)
    uv3 = np.concatenate([piece.uvs, np.zeros((len(piece.uvs), 1))], axis=1)
    density = triangle_areas(uv3, f).sum() / triangle_areas(v, f).sum()
    assert 0.95 < density < 1.06


def test_box_volume_and_merge() -> None:
    a = box([0, 0, 0], [1.0, 2.0, 3.0])
    assert _welded(a).volume == pytest.approx(6.0)
    merged = merge_pieces([a, box([5, 0, 0], [1, 1, 1])])
    assert len(merged.faces) == 24 and merged.faces.max() == len(merged.vertices) - 1
    assert _welded(merged).volume == pytest.approx(7.0)


def test_scaling_keeps_uvs_in_world_units() -> None:
    piece = rounded_box([0, 0, 0], [2.0, 1.0, 1.0], 0.1)
    small = piece.scaled(0.5, np.zeros(3))
    np.testing.assert_allclose(small.uvs, 0.5 * piece.uvs)
    np.testing.assert_allclose(small.vertices, 0.5 * piece.vertices)
