"""Closed mesh primitives with normals and world-unit UVs, the building blocks of demo furniture.

Every primitive is a `Piece`: vertices, triangles, per-vertex normals and UVs. UVs are in world
units (box / cylindrical / arc-length projection) so the UV density A_uv / A_world of a part is
close to 1 whatever its size, as real models unwrapped with a smart projection roughly are.
Vertices are split along sharp edges and UV seams, but every primitive is closed: merging
coincident positions makes it watertight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Piece:
    """A triangle mesh fragment: one object group (`g`) inside a material part."""

    vertices: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64, counter-clockwise seen from outside
    normals: np.ndarray  # (n, 3) float64, unit length
    uvs: np.ndarray  # (n, 2) float64, world units

    def transformed(self, rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> Piece:
        """Rigidly move the piece (rotation then translation); UVs keep their world units."""
        rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
        return Piece(
            vertices=self.vertices @ rot.T + np.asarray(translation, np.float64),
            faces=self.faces.copy(),
            normals=self.normals @ rot.T,
            uvs=self.uvs.copy(),
        )

    def scaled(self, factor: float, centre: np.ndarray) -> Piece:
        """Uniform scale about `centre`; UVs scale too so they stay in world units."""
        return Piece(
            vertices=(self.vertices - centre) * factor,
            faces=self.faces.copy(),
            normals=self.normals.copy(),
            uvs=self.uvs * factor,
        )


def merge_pieces(pieces: list[Piece]) -> Piece:
    """Concatenate pieces into one (faces re-indexed)."""
    verts, faces, normals, uvs = [], [], [], []
    offset = 0
    for p in pieces:
        verts.append(p.vertices)
        faces.append(p.faces + offset)
        normals.append(p.normals)
        uvs.append(p.uvs)
        offset += len(p.vertices)
    return Piece(np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(uvs))


def _normalise(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], np.float64)


def rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], np.float64)


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float64)


def frame_from_axis(axis: np.ndarray) -> np.ndarray:
    """A rotation whose y column is `axis` (primitives are built along +y)."""
    y = _normalise(np.asarray(axis, np.float64))
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    z = _normalise(np.cross(helper, y))
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


# -- faceted solids -------------------------------------------------------------------------------

# Corner order of a hexahedron: bit 0 = +x, bit 1 = +y, bit 2 = +z.
_HEX_FACES = (
    (0, 4, 6, 2),  # -x
    (1, 3, 7, 5),  # +x
    (0, 1, 5, 4),  # -y
    (2, 6, 7, 3),  # +y
    (0, 2, 3, 1),  # -z
    (4, 5, 7, 6),  # +z
)


def hexahedron(corners: np.ndarray) -> Piece:
    """A six-sided solid from 8 corners (bit order x, y, z); each face planar-projected for UVs.

    Flat shaded: every face has its own 4 vertices with the face normal, so hard edges stay hard.
    Covers boxes, tapered legs and wedge-like slabs.
    """
    c = np.asarray(corners, np.float64)
    verts, faces, normals, uvs = [], [], [], []
    for k, quad in enumerate(_HEX_FACES):
        q = c[list(quad)]
        n = _normalise(np.cross(q[1] - q[0], q[3] - q[0]) + np.cross(q[3] - q[2], q[1] - q[2]))
        # in-plane basis: first edge direction and its perpendicular inside the face plane
        e0 = _normalise(q[1] - q[0])
        e1 = np.cross(n, e0)
        rel = q - q[0]
        uv = np.stack([rel @ e0, rel @ e1], axis=1)
        base = 4 * k
        verts.append(q)
        normals.append(np.repeat(n[None], 4, axis=0))
        uvs.append(uv)
        faces.append([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    return Piece(
        np.concatenate(verts), np.asarray(faces, np.int64).reshape(-1, 3), np.concatenate(normals), np.concatenate(uvs)
    )


def box(centre, size, rotation: np.ndarray | None = None) -> Piece:
    """Axis-aligned box of `size` (before `rotation`) centred at `centre`."""
    h = np.asarray(size, np.float64) / 2
    corners = (
        np.array(
            [[(-1) ** (1 - (i & 1)), (-1) ** (1 - ((i >> 1) & 1)), (-1) ** (1 - ((i >> 2) & 1))] for i in range(8)],
            np.float64,
        )
        * h
    )
    return hexahedron(corners).transformed(rotation, centre)


def tapered_box(bottom_centre, top_centre, bottom_size, top_size) -> Piece:
    """A square-section leg whose section goes from `bottom_size` (x, z) to `top_size` (x, z).

    The two end faces stay horizontal, so a slanted (splayed) leg still stands flat on the floor.
    """
    b = np.asarray(bottom_centre, np.float64)
    t = np.asarray(top_centre, np.float64)
    corners = []
    for i in range(8):
        sx = 1.0 if i & 1 else -1.0
        sz = 1.0 if (i >> 2) & 1 else -1.0
        top = (i >> 1) & 1
        centre, size = (t, top_size) if top else (b, bottom_size)
        corners.append(centre + np.array([sx * size[0] / 2, 0.0, sz * size[1] / 2]))
    return hexahedron(np.asarray(corners))


# -- rounded box ----------------------------------------------------------------------------------


def _rounded_axis(h: float, r: float, n_flat: int, n_round: int) -> tuple[np.ndarray, np.ndarray]:
    """Face coordinates along one axis of a rounded-box face and their arc-length UVs.

    Points in [h - r, h] sit on the rounding; they are spaced uniformly in angle (tan mapping) so
    the 45 degrees each face owns of a rounded edge are evenly sampled.
    """
    inner = h - r
    theta = np.linspace(0.0, np.pi / 4, n_round + 1)[1:]
    edge = inner + r * np.tan(theta)
    edge[-1] = h
    edge_uv = inner + r * theta
    flat = np.linspace(-inner, inner, n_flat + 1)
    coords = np.concatenate([-edge[::-1], flat, edge])
    arc = np.concatenate([-edge_uv[::-1], flat, edge_uv])
    return coords, arc


def rounded_box(
    centre, size, radius: float, rotation: np.ndarray | None = None, *, n_flat: int = 2, n_round: int = 3
) -> Piece:
    """A box with rounded edges and corners (cushions, upholstered seats): a subdivided cube whose
    points are pushed onto the offset surface of the inner box, with exact normals.
    """
    h = np.asarray(size, np.float64) / 2
    r = float(min(radius, *(h * 0.999)))
    inner = h - r
    axes = [_rounded_axis(h[i], r, n_flat, n_round) for i in range(3)]
    verts, faces, normals, uvs = [], [], [], []
    offset = 0
    for axis in range(3):
        a, b = [i for i in range(3) if i != axis]
        ca, ua = axes[a]
        cb, ub = axes[b]
        for sign in (-1.0, 1.0):
            A, B = np.meshgrid(ca, cb, indexing="ij")
            UA, UB = np.meshgrid(ua, ub, indexing="ij")
            p = np.zeros(A.shape + (3,))
            p[..., a] = A
            p[..., b] = B
            p[..., axis] = sign * h[axis]
            q = np.clip(p, -inner, inner)
            d = _normalise(p - q)
            pos = q + r * d
            na, nb = A.shape
            idx = np.arange(na * nb).reshape(na, nb) + offset
            i00, i10, i01, i11 = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
            # orientation: (a, b, axis) right-handed when b follows a cyclically
            right_handed = (a + 1) % 3 == b
            outward = (sign > 0) == right_handed
            if outward:
                tri = np.concatenate(
                    [np.stack([i00, i10, i11], -1).reshape(-1, 3), np.stack([i00, i11, i01], -1).reshape(-1, 3)]
                )
            else:
                tri = np.concatenate(
                    [np.stack([i00, i11, i10], -1).reshape(-1, 3), np.stack([i00, i01, i11], -1).reshape(-1, 3)]
                )
            verts.append(pos.reshape(-1, 3))
            normals.append(d.reshape(-1, 3))
            uvs.append(np.stack([UA, UB], -1).reshape(-1, 2) * np.array([sign if outward else -sign, 1.0]))
            faces.append(tri)
            offset += na * nb
    piece = Piece(np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(uvs))
    return piece.transformed(rotation, centre)


# -- round solids ---------------------------------------------------------------------------------


def _ring(n: int) -> tuple[np.ndarray, np.ndarray]:
    """cos/sin of n+1 angles around the circle; the last equals the first exactly (seam)."""
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    c, s = np.cos(t), np.sin(t)
    c[-1], s[-1] = c[0], s[0]
    return c, s


def _cap(centre: np.ndarray, ring: np.ndarray, normal: np.ndarray, flip: bool) -> Piece:
    """A triangle fan closing a ring (ring given without its seam duplicate)."""
    n = len(ring)
    verts = np.concatenate([centre[None], ring])
    e0 = _normalise(ring[0] - centre)
    e1 = np.cross(normal, e0)
    rel = verts - centre
    uv = np.stack([rel @ e0, rel @ e1], axis=1)
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.stack([np.zeros(n, np.int64), 1 + i, 1 + j], axis=1)
    if flip:
        faces = faces[:, [0, 2, 1]]
    return Piece(verts, faces, np.repeat(normal[None], n + 1, axis=0), uv)


def tube(path: np.ndarray, radii, segments: int = 16, caps: bool = True) -> Piece:
    """A circular tube swept along a polyline (parallel-transport frames); radius per path point.

    UVs: u = arc length around the section (angle x mean radius), v = arc length along the path,
    i.e. a cylindrical projection in world units. Straight cylinders and frustums are the 2-point case.
    """
    path = np.asarray(path, np.float64)
    m = len(path)
    radii = np.broadcast_to(np.asarray(radii, np.float64), (m,)).copy()
    tangents = np.zeros_like(path)
    tangents[0] = path[1] - path[0]
    tangents[-1] = path[-1] - path[-2]
    if m > 2:
        tangents[1:-1] = _normalise(path[1:-1] - path[:-2]) + _normalise(path[2:] - path[1:-1])
    tangents = _normalise(tangents)
    frame = frame_from_axis(tangents[0])
    normals_pt = [frame[:, 0]]
    for k in range(1, m):  # parallel transport of the section's reference direction
        nprev = normals_pt[-1]
        n = nprev - tangents[k] * (nprev @ tangents[k])
        normals_pt.append(_normalise(n))
    nvec = np.asarray(normals_pt)
    bvec = np.cross(tangents, nvec)
    c, s = _ring(segments)
    # slope of the radius along the path tilts the side normals of a frustum
    seglen = np.linalg.norm(np.diff(path, axis=0), axis=1)
    vcoord = np.concatenate([[0.0], np.cumsum(seglen)])
    dr = np.gradient(radii, vcoord) if m > 1 and vcoord[-1] > 0 else np.zeros(m)
    dirs = c[None, :, None] * nvec[:, None, :] + s[None, :, None] * bvec[:, None, :]
    pos = path[:, None, :] + radii[:, None, None] * dirs
    side_n = _normalise(dirs - dr[:, None, None] * tangents[:, None, :])
    mean_r = float(radii.mean())
    u = np.linspace(0.0, 2 * np.pi * mean_r, segments + 1)
    U, V = np.meshgrid(u, vcoord)
    idx = np.arange(m * (segments + 1)).reshape(m, segments + 1)
    i00, i01, i10, i11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    tri = np.concatenate([np.stack([i00, i01, i11], -1).reshape(-1, 3), np.stack([i00, i11, i10], -1).reshape(-1, 3)])
    pieces = [Piece(pos.reshape(-1, 3), tri, side_n.reshape(-1, 3), np.stack([U, V], -1).reshape(-1, 2))]
    if caps:
        pieces.append(_cap(path[0], pos[0, :-1], -tangents[0], flip=False))
        pieces.append(_cap(path[-1], pos[-1, :-1], tangents[-1], flip=True))
    piece = merge_pieces(pieces)
    _orient_outward(piece)
    return piece


def cylinder(p0, p1, r0: float, r1: float | None = None, segments: int = 16) -> Piece:
    """A closed (possibly tapered) cylinder from p0 (radius r0) to p1 (radius r1)."""
    return tube(np.array([p0, p1], np.float64), [r0, r0 if r1 is None else r1], segments)


def rounded_path(points: np.ndarray, radius: float, steps: int = 6) -> np.ndarray:
    """Replace each interior corner of a polyline by a circular-ish fillet (quadratic Bezier)."""
    pts = np.asarray(points, np.float64)
    out = [pts[0]]
    for k in range(1, len(pts) - 1):
        a, b, c = pts[k - 1], pts[k], pts[k + 1]
        la, lc = np.linalg.norm(a - b), np.linalg.norm(c - b)
        d = min(radius, 0.45 * la, 0.45 * lc)
        p = b + (a - b) / la * d
        q = b + (c - b) / lc * d
        t = np.linspace(0.0, 1.0, steps)[:, None]
        out.extend((1 - t) ** 2 * p + 2 * (1 - t) * t * b + t**2 * q)
    out.append(pts[-1])
    return np.asarray(out)


def _orient_outward(piece: Piece) -> None:
    """Flip every face whose winding disagrees with its vertices' normals (in place)."""
    v, f, n = piece.vertices, piece.faces, piece.normals
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = n[f].sum(axis=1)
    flip = (fn * vn).sum(axis=1) < 0
    f[flip] = f[flip][:, [0, 2, 1]]
