"""A tiny procedural chair (box parts) and a studio-like envmap, for tests and smoke runs.

Not the demo generator (``photoshape_flow.demo``): just enough geometry to exercise the
training-render and substance code paths in a few milliseconds.
"""

from __future__ import annotations

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh


def _box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """24 vertices (4 per face, flat normals), 12 triangles, UVs = face-plane world coordinates."""
    verts, norms, uvs, faces = [], [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_axis, v_axis = [a for a in range(3) if a != axis]
            e_u, e_v = np.eye(3)[u_axis], np.eye(3)[v_axis]
            if np.cross(e_u, e_v)[axis] * sign < 0:
                u_axis, v_axis = v_axis, u_axis  # counter-clockwise seen from outside
            base = len(verts)
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = np.empty(3)
                p[axis] = hi[axis] if sign > 0 else lo[axis]
                p[u_axis] = hi[u_axis] if du else lo[u_axis]
                p[v_axis] = hi[v_axis] if dv else lo[v_axis]
                n = np.zeros(3)
                n[axis] = sign
                verts.append(p)
                norms.append(n)
                uvs.append((p[u_axis], p[v_axis]))
            faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return (
        np.asarray(verts, np.float32),
        np.asarray(faces, np.int32),
        np.asarray(norms, np.float32),
        np.asarray(uvs, np.float32),
    )


def _merge(boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]):  # type: ignore[no-untyped-def]
    v, f, n, t = [], [], [], []
    offset = 0
    for bv, bf, bn, bt in boxes:
        v.append(bv)
        f.append(bf + offset)
        n.append(bn)
        t.append(bt)
        offset += len(bv)
    return np.concatenate(v), np.concatenate(f), np.concatenate(n), np.concatenate(t)


def toy_chair(seat_height: float = 0.45, back_height: float = 0.5, leg: float = 0.05) -> ShapeMesh:
    """A chair of three parts: 1 seat, 2 back, 3 legs (four boxes), normalised to the unit cube."""
    w = 0.45
    seat_t = 0.06
    seat = _box(np.array([-w / 2, seat_height, -w / 2]), np.array([w / 2, seat_height + seat_t, w / 2]))
    back = _box(
        np.array([-w / 2, seat_height + seat_t, -w / 2]),
        np.array([w / 2, seat_height + seat_t + back_height, -w / 2 + 0.05]),
    )
    legs = []
    for x in (-w / 2, w / 2 - leg):
        for z in (-w / 2, w / 2 - leg):
            legs.append(_box(np.array([x, 0.0, z]), np.array([x + leg, seat_height, z + leg])))
    parts_raw = [("seat", seat), ("back", back), ("legs", _merge(legs))]
    allv = np.concatenate([p[1][0] for p in parts_raw])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    centre, extent = (lo + hi) / 2, float((hi - lo).max())
    colours = {"seat": [0.6, 0.2, 0.2], "back": [0.2, 0.3, 0.6], "legs": [0.4, 0.3, 0.2]}
    parts = []
    for index, (name, (v, f, n, t)) in enumerate(parts_raw, start=1):
        parts.append(
            PartMesh(
                index=index,
                name=name,
                vertices=((v - centre) / extent).astype(np.float32),
                faces=f,
                normals=n,
                uvs=(t / extent).astype(np.float32),
                builtin_material={"albedo": colours[name], "roughness": 0.5, "metallic": 0.0, "name": name},
            )
        )
    return ShapeMesh(parts=parts, meta={"source": "toy"})


def studio_envmap(width: int = 64, height: int = 32, sun: float = 4.0) -> np.ndarray:
    """A float32 equirectangular map: grey sky gradient plus one bright soft light above the front."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    theta = (y + 0.5) / height * np.pi  # 0 at the zenith
    phi = (x + 0.5) / width * 2 * np.pi
    sky = 0.4 + 0.4 * np.cos(theta).clip(0, 1)
    d = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), np.sin(theta) * np.cos(phi)], -1)
    light_dir = np.array([0.3, 0.8, 0.5], np.float32)
    light_dir /= np.linalg.norm(light_dir)
    spot = sun * np.exp((d @ light_dir - 1.0) * 20.0)
    image = (sky + spot)[..., None] * np.array([1.0, 0.98, 0.95], np.float32)
    return image.astype(np.float32)
