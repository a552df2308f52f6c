"""Smooth vertex normals with a crease angle ("auto smooth"), computed per face corner.

The paper enables smooth shading after removing doubles; the original code also split edges sharper
than 20 degrees first. A plain vertex average darkens the flat faces of boxy furniture, so each corner
averages the (area-weighted) normals of the faces around its position that lie within the crease
angle of its own face. Faces with opposite winding never average together, which also makes
inconsistently oriented source meshes shade sensibly.
"""

from __future__ import annotations

import numpy as np

# Above this many (corner, neighbour) pairs a plain smooth average is used (pathological fans).
MAX_CORNER_PAIRS = 20_000_000


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalised face normals (length = twice the area)."""
    v = np.asarray(vertices, np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return np.cross(b - a, c - a)


def _normalise(n: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def corner_normals(
    vertices: np.ndarray, faces: np.ndarray, position_ids: np.ndarray, crease_angle_deg: float = 30.0
) -> np.ndarray:
    """(m, 3, 3) unit normals per face corner.

    `position_ids[v]` names the welded position of vertex v: corners at the same position (even
    across UV seams) share normals unless their faces meet at more than the crease angle.
    """
    faces = np.asarray(faces, np.int64)
    m = len(faces)
    fn = face_normals(vertices, faces)
    fu = _normalise(fn)
    corner_face = np.repeat(np.arange(m), 3)
    corner_pos = np.asarray(position_ids, np.int64)[faces.ravel()]
    order = np.argsort(corner_pos, kind="stable")
    sorted_pos = corner_pos[order]
    starts = np.flatnonzero(np.r_[True, sorted_pos[1:] != sorted_pos[:-1]])
    sizes = np.diff(np.r_[starts, len(sorted_pos)])
    pair_count = int((sizes.astype(np.int64) ** 2).sum())
    if crease_angle_deg >= 180.0 or pair_count > MAX_CORNER_PAIRS:
        # plain area-weighted average per position
        n_pos = int(corner_pos.max()) + 1 if len(corner_pos) else 0
        acc = np.zeros((n_pos, 3))
        for k in range(3):
            acc[:, k] = np.bincount(corner_pos, weights=fn[corner_face, k], minlength=n_pos)
        normals = _normalise(acc)[corner_pos]
    else:
        # every (corner i, corner j) pair at the same position
        group_of_sorted = np.repeat(np.arange(len(starts)), sizes)
        size_per = sizes[group_of_sorted]
        start_per = starts[group_of_sorted]
        i_sorted = np.repeat(np.arange(len(sorted_pos)), size_per)
        offsets = np.arange(len(i_sorted)) - np.repeat(np.cumsum(size_per) - size_per, size_per)
        j_sorted = np.repeat(start_per, size_per) + offsets
        ci = order[i_sorted]
        cj = order[j_sorted]
        fi = corner_face[ci]
        fj = corner_face[cj]
        cos_limit = np.cos(np.deg2rad(crease_angle_deg)) - 1e-9
        keep = (fu[fi] * fu[fj]).sum(axis=1) >= cos_limit
        keep |= fi == fj
        ci, fj = ci[keep], fj[keep]
        acc = np.zeros((3 * m, 3))
        for k in range(3):
            acc[:, k] = np.bincount(ci, weights=fn[fj, k], minlength=3 * m)
        normals = _normalise(acc)
    # fall back to the face normal where the average vanished (opposite faces, zero area)
    missing = np.linalg.norm(normals, axis=1) < 0.5
    if missing.any():
        normals[missing] = fu[corner_face[missing]]
    still = np.linalg.norm(normals, axis=1) < 0.5
    normals[still] = (0.0, 1.0, 0.0)
    return normals.reshape(m, 3, 3)


def split_vertices(
    faces: np.ndarray, corner_normal: np.ndarray, quantum: float = 1e-4
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique (vertex, normal) per corner -> (source vertex of each new vertex, new faces, normals)."""
    m = len(faces)
    quantised = np.round(corner_normal.reshape(-1, 3) / quantum).astype(np.int64)
    key = np.concatenate([np.asarray(faces, np.int64).reshape(-1, 1), quantised], axis=1)
    uniq, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    new_faces = inverse.reshape(m, 3).astype(np.int32)
    normals = corner_normal.reshape(-1, 3)[first]
    return uniq[:, 0], new_faces, normals
