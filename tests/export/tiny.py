"""Tiny generated inputs shared by the export and publish tests: a 2-part shape, two SVBRDF materials."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh


def box_part(index: int, name: str, lo: tuple[float, float, float], hi: tuple[float, float, float],
             builtin: dict | None = None) -> PartMesh:
    """An axis-aligned box with 4 vertices per face (flat normals, per-face UVs in world units)."""
    lo_a, hi_a = np.asarray(lo, np.float32), np.asarray(hi, np.float32)
    vertices, normals, uvs, faces = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_axis, v_axis = [a for a in range(3) if a != axis]
            base = len(vertices)
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = np.where(sign > 0, hi_a, lo_a).copy()
                p[u_axis] = (lo_a if du == 0 else hi_a)[u_axis]
                p[v_axis] = (lo_a if dv == 0 else hi_a)[v_axis]
                vertices.append(p)
                n = np.zeros(3, np.float32)
                n[axis] = sign
                normals.append(n)
                uvs.append([p[u_axis], p[v_axis]])
            tri = [(0, 1, 2), (0, 2, 3)]
            # outward winding: flip when the face's cross product points inwards
            e1, e2 = vertices[base + 1] - vertices[base], vertices[base + 2] - vertices[base]
            if np.dot(np.cross(e1, e2), normals[base]) < 0:
                tri = [(0, 2, 1), (0, 3, 2)]
            faces.extend([[base + a, base + b, base + c] for a, b, c in tri])
    return PartMesh(
        index=index, name=name, vertices=np.asarray(vertices, np.float32), faces=np.asarray(faces, np.int32),
        normals=np.asarray(normals, np.float32), uvs=np.asarray(uvs, np.float32) * 2.0,
        builtin_material=builtin or {"albedo": [0.6, 0.3, 0.2], "roughness": 0.6, "metallic": 0.0, "name": name},
    )


def make_tiny_shape() -> ShapeMesh:
    """A 'seat' slab (part 1) on a 'leg' box (part 2), in the unit cube."""
    seat = box_part(1, "seat", (-0.5, -0.05, -0.5), (0.5, 0.05, 0.5))
    leg = box_part(2, "leg", (-0.1, -0.5, -0.1), (0.1, -0.05, 0.1),
                   builtin={"albedo": [0.2, 0.2, 0.25], "roughness": 0.3, "metallic": 1.0, "name": "chrome"})
    return ShapeMesh(parts=[seat, leg], meta={"name": "tiny-chair"})


def write_png(path: Path, array: np.ndarray) -> Path:
    from PIL import Image

    Image.fromarray(array).save(path)
    return path


def make_material_maps(folder: Path) -> dict[str, dict[str, Path]]:
    """Maps of two materials: 'oak_01' (albedo, roughness, normal), 'steel_02' (albedo, roughness, metallic)."""
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    y, x = np.mgrid[0:16, 0:16]
    stripes = (128 + 100 * np.sin(x / 2.0)).astype(np.uint8)
    oak_albedo = np.stack([stripes, (stripes * 0.7).astype(np.uint8), (stripes * 0.4).astype(np.uint8)], axis=2)
    normal = np.zeros((16, 16, 3), np.uint8)
    normal[..., 0] = (128 + 40 * np.cos(x / 2.0)).astype(np.uint8)
    normal[..., 1] = 128
    normal[..., 2] = 240
    return {
        "oak_01": {
            "albedo": write_png(folder / "oak_albedo.png", oak_albedo),
            "roughness": write_png(folder / "oak_rough.png", rng.integers(120, 200, (16, 16), dtype=np.uint8)),
            "normal": write_png(folder / "oak_normal.png", normal),
        },
        "steel_02": {
            "albedo": write_png(folder / "steel_albedo.png", np.full((8, 8, 3), 180, np.uint8)),
            "roughness": write_png(folder / "steel_rough.png", rng.integers(30, 90, (8, 8), dtype=np.uint8)),
            "metallic": write_png(folder / "steel_metal.png", np.full((8, 8), 250, np.uint8)),
        },
    }


def make_envmap() -> np.ndarray:
    """A small lat-long radiance map (float32 RGB): a bright sky over a dimmer ground, slightly blue."""
    env = np.ones((16, 32, 3), np.float32)
    env[:8] *= 3.0
    env[..., 2] += 0.3
    return env
