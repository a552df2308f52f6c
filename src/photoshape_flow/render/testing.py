"""Procedural shapes for tests, benchmarks and the renderer self-test (no files, numpy only).

`procedural_chair` builds a multi-part chair from superquadric patches (seat, back, four legs, two
arm rests, a cushion) with smooth normals and UVs in world units (uv_density ~ 1), normalised to the
unit cube like ingested shapes. `quad_part` and `box_part` give exact, simple geometry whose
projection tests can predict.
"""

from __future__ import annotations

import math

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh
from photoshape_flow.render.camera import Camera


def quad_part(
    index: int,
    corners: np.ndarray | list[list[float]],
    name: str | None = None,
    uv_size: tuple[float, float] = (1.0, 1.0),
) -> PartMesh:
    """A planar quad from 4 corners in counter-clockwise order seen from the front.

    UV (0, 0) at corner 0, (uv_size[0], 0) at corner 1, and so on (OBJ convention, v up).
    """
    v = np.asarray(corners, np.float32).reshape(4, 3)
    normal = np.cross(v[1] - v[0], v[3] - v[0])
    normal = (normal / np.linalg.norm(normal)).astype(np.float32)
    su, sv = uv_size
    return PartMesh(
        index=index,
        name=name or f"quad{index}",
        vertices=v,
        faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
        normals=np.tile(normal, (4, 1)),
        uvs=np.array([[0, 0], [su, 0], [su, sv], [0, sv]], np.float32),
    )


def box_part(
    index: int, centre: tuple[float, float, float], half: tuple[float, float, float], name: str | None = None
) -> PartMesh:
    """An axis-aligned box with flat faces (24 vertices, 12 triangles) and per-face UVs in world units."""
    c, h = np.asarray(centre, np.float64), np.asarray(half, np.float64)
    vertices, normals, uvs, faces = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u_axis, v_axis = [a for a in range(3) if a != axis]
            u = np.zeros(3)
            u[u_axis] = 1.0
            v = np.cross(n, u)
            base = len(vertices)
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                vertices.append(c + n * h[axis] + su * u * h[u_axis] + sv * v * h[v_axis])
                normals.append(n)
                uvs.append([su * h[u_axis], sv * h[v_axis]])
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return PartMesh(
        index=index,
        name=name or f"box{index}",
        vertices=np.asarray(vertices, np.float32),
        faces=np.asarray(faces, np.int32),
        normals=np.asarray(normals, np.float32),
        uvs=np.asarray(uvs, np.float32),
    )


def _signed_pow(x: np.ndarray, e: float) -> np.ndarray:
    return np.sign(x) * np.abs(x) ** e


def superquadric_part(
    index: int,
    name: str,
    centre: tuple[float, float, float],
    radii: tuple[float, float, float],
    exponent: float,
    rings: int,
    segments: int,
) -> PartMesh:
    """A closed superquadric patch grid (exponent 1: ellipsoid; small: box-like), rings x segments quads."""
    theta = np.linspace(-math.pi / 2, math.pi / 2, rings + 1)
    phi = np.linspace(-math.pi, math.pi, segments + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ct, st = _signed_pow(np.cos(t), exponent), _signed_pow(np.sin(t), exponent)
    cp, sp = _signed_pow(np.cos(p), exponent), _signed_pow(np.sin(p), exponent)
    r = np.asarray(radii)
    local = np.stack([ct * cp * r[0], st * r[1], ct * sp * r[2]], axis=-1)
    vertices = (local + np.asarray(centre)).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings), np.arange(segments), indexing="ij")
    a = (i * (segments + 1) + j).ravel()
    b, c, d = a + segments + 1, a + segments + 2, a + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    # smooth normals: area-weighted face normals accumulated on vertices
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], fn)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 1e-12, normals / np.maximum(length, 1e-12), np.array([0.0, 1.0, 0.0]))
    # UVs in world units: arc length along both grid directions
    grid = vertices.reshape(rings + 1, segments + 1, 3)
    du = np.concatenate([np.zeros((rings + 1, 1)), np.cumsum(np.linalg.norm(np.diff(grid, axis=1), axis=2), 1)], 1)
    dv = np.concatenate([np.zeros((1, segments + 1)), np.cumsum(np.linalg.norm(np.diff(grid, axis=0), axis=2), 0)], 0)
    uvs = np.stack([du, dv], axis=-1).reshape(-1, 2)
    return PartMesh(
        index=index,
        name=name,
        vertices=vertices.astype(np.float32),
        faces=faces,
        normals=normals.astype(np.float32),
        uvs=uvs.astype(np.float32),
    )


def normalise_to_unit_cube(parts: list[PartMesh]) -> ShapeMesh:
    """Centre the bounding box at the origin and scale its longest side to 1 (the mesh contract)."""
    allv = np.concatenate([p.vertices for p in parts]).astype(np.float64)
    lo, hi = allv.min(0), allv.max(0)
    centre, scale = (lo + hi) / 2, 1.0 / float((hi - lo).max())
    for p in parts:
        p.vertices = ((p.vertices - centre) * scale).astype(np.float32)
        p.uvs = (p.uvs * scale).astype(np.float32)
    return ShapeMesh(parts=parts, meta={"generator": "procedural"})


def procedural_chair(target_faces: int = 50_000) -> ShapeMesh:
    """A chair of 9 parts with about `target_faces` triangles (seat, back, legs, arms, cushion)."""
    specs = [
        # name, centre, radii, exponent, share of triangles
        ("seat", (0.0, 0.45, 0.0), (0.5, 0.06, 0.5), 0.2, 0.16),
        ("back", (0.0, 1.0, -0.45), (0.5, 0.5, 0.06), 0.2, 0.16),
        ("leg_fl", (0.4, 0.2, 0.4), (0.04, 0.22, 0.04), 0.6, 0.07),
        ("leg_fr", (-0.4, 0.2, 0.4), (0.04, 0.22, 0.04), 0.6, 0.07),
        ("leg_bl", (0.4, 0.2, -0.4), (0.04, 0.22, 0.04), 0.6, 0.07),
        ("leg_br", (-0.4, 0.2, -0.4), (0.04, 0.22, 0.04), 0.6, 0.07),
        ("arm_l", (0.52, 0.7, 0.0), (0.05, 0.04, 0.45), 0.4, 0.1),
        ("arm_r", (-0.52, 0.7, 0.0), (0.05, 0.04, 0.45), 0.4, 0.1),
        ("cushion", (0.0, 0.55, 0.05), (0.42, 0.06, 0.4), 0.7, 0.2),
    ]
    parts = []
    for k, (name, centre, radii, exponent, share) in enumerate(specs, start=1):
        quads = max(8, int(target_faces * share / 2))
        rings = max(4, int(math.sqrt(quads / 2)))
        segments = max(8, quads // rings)
        parts.append(superquadric_part(k, name, centre, radii, exponent, rings, segments))
    return normalise_to_unit_cube(parts)


def paper_viewpoints(distance: float = 2.0, fov: float = 50.0, equator: int = 50, rings: int = 10) -> list:
    """The paper's coarse-alignment views: phi in linspace(pi/4, 9pi/16, rings), round(equator * sin phi)
    azimuths each over [0, 2pi); 456 views with the defaults (section 4.1)."""
    cameras = []
    for phi in np.linspace(math.pi / 4, 9 * math.pi / 16, rings):
        count = int(round(equator * math.sin(phi)))
        for az in np.arange(count) * 2 * math.pi / count:
            cameras.append(Camera(float(az), float(math.pi / 2 - phi), distance, fov))
    return cameras
