"""Shape preprocessing of section 3.1: remove vertex doubles, smooth shading, unit cube, UVs per part.

Steps, per material part: weld positions closer than a tolerance (pymeshlab merge_close_vertices;
per-corner "wedge" UVs ride along so source UV seams survive), drop null and degenerate triangles,
then normalise the whole shape into the unit cube (mesh contract), generate UVs with xatlas where
the source has none (the paper used Blender's Smart UV Project per material segment; xatlas is the
open equivalent; a box projection takes over above a face budget), and compute crease-aware smooth
normals. D_i = A_uv / A_world is then a property of each `PartMesh`.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from photoshape_flow.export.text import hidden_character, one_line
from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh, triangle_areas
from photoshape_flow.geometry.normals import corner_normals, split_vertices
from photoshape_flow.geometry.raw import BadShapeError, RawPart, RawShape

PREPROCESS_VERSION = 1  # bump when the output of `preprocess` changes for the same input
MAX_COORDINATE = 1e12  # |x|, |y|, |z| of any vertex: a city in micrometres fits; 1e308 would overflow extents
# xatlas' task scheduler (0.0.11) can hang for good when an atlas is destroyed: the destructor raises
# a worker's wake-up flag without the worker's mutex, so a worker between reading the flag and going
# to sleep misses it and the destructor's join waits for ever (a loop over degenerate parts hung
# within 2,000-8,000 atlases, 4 runs of 4; the suite's fuzz test hung once). A worker is in that
# window only just after it started or ran a task, so each atlas is destroyed late: once this many
# newer ones exist *and* it has been retired this long. The count alone (4) ran 600,000 atlases
# without a hang, yet hung once in the suite on a loaded 2-core machine, where a starved worker can
# wait longer than 4 quick atlases take; a time slice on a busy Linux scheduler is a few ms to 24 ms.
RETIRED_ATLASES = 4
RETIRED_SECONDS = 0.05
# each atlas holds its own worker threads (cores - 1): beyond this many retired the unwrap waits for
# the oldest's time instead of holding more threads (only a loop of near-empty parts gets here)
RETIRED_CAP = 256
_retired: deque[tuple[float, Any]] = deque()
_retired_lock = threading.Lock()


@dataclass(frozen=True)
class PreprocessOptions:
    merge_tolerance: float = 1e-5  # vertex welding distance, relative to the bounding-box diagonal
    degenerate_area: float = 1e-12  # triangles below this area (relative to diagonal^2) are dropped
    crease_angle_deg: float = 30.0
    xatlas_max_faces: int = 200_000  # larger UV-less parts get a box projection instead
    xatlas_iterations: int = 0  # chart-growing refinement passes; 0 halves the time on curved meshes
    xatlas_max_chart_area: float = 0.1  # unit-cube units^2; big charts dominate xatlas' time (5.4 s -> 1.7 s
    # on a 17k-face curved band) and a 30 cm tile on a 1 m chair is still a large seamless region
    rotation: tuple[float, ...] | None = None  # row-major 3x3 applied to source coordinates

    def as_dict(self) -> dict[str, Any]:
        return {
            "version": PREPROCESS_VERSION,
            "merge_tolerance": self.merge_tolerance,
            "degenerate_area": self.degenerate_area,
            "crease_angle_deg": self.crease_angle_deg,
            "xatlas_max_faces": self.xatlas_max_faces,
            "xatlas_iterations": self.xatlas_iterations,
            "xatlas_max_chart_area": self.xatlas_max_chart_area,
        }


@dataclass
class _Clean:
    raw: RawPart
    vertices: np.ndarray  # welded positions
    faces: np.ndarray  # (m, 3) into vertices
    corner_uvs: np.ndarray | None  # (m, 3, 2) source UVs per corner


def _weld(part: RawPart, tolerance: float, min_area: float) -> _Clean:
    """Merge close vertices and drop null faces with pymeshlab, keeping per-corner UVs."""
    import pymeshlab

    faces = np.asarray(part.faces, np.int64)
    vertices = np.asarray(part.vertices, np.float64)
    wedge = None
    if part.uvs is not None:
        wedge = np.asarray(part.uvs, np.float64)[faces].reshape(-1, 2)
    mesh = pymeshlab.Mesh(
        vertex_matrix=vertices,
        face_matrix=faces.astype(np.int32),
        **({"w_tex_coords_matrix": wedge} if wedge is not None else {}),
    )
    ms = pymeshlab.MeshSet()
    ms.add_mesh(mesh)
    if tolerance > 0:
        ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(float(tolerance)))
    ms.meshing_remove_null_faces()
    ms.meshing_remove_unreferenced_vertices()
    out = ms.current_mesh()
    v = np.asarray(out.vertex_matrix(), np.float64)
    f = np.asarray(out.face_matrix(), np.int64).reshape(-1, 3)
    uv = None
    if wedge is not None and out.has_wedge_tex_coord():
        uv = np.asarray(out.wedge_tex_coord_matrix(), np.float64).reshape(-1, 3, 2)
    # degenerate: repeated indices or (near) zero area
    if len(f):
        keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        keep &= triangle_areas(v, f) > min_area
        f = f[keep]
        if uv is not None:
            uv = uv[keep]
    return _Clean(raw=part, vertices=v, faces=f, corner_uvs=uv)


def _box_uvs(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-corner UVs by projecting each face on the plane of its dominant normal axis."""
    n = np.abs(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]))
    axis = np.argmax(n, axis=1)
    planes = np.array([[2, 1], [0, 2], [0, 1]])[axis]  # x-dominant -> (z, y), y -> (x, z), z -> (x, y)
    corners = vertices[faces]  # (m, 3, 3)
    u = np.take_along_axis(corners, planes[:, None, 0:1].repeat(3, axis=1), axis=2)[..., 0]
    v = np.take_along_axis(corners, planes[:, None, 1:2].repeat(3, axis=1), axis=2)[..., 0]
    return np.stack([u, v], axis=2)


def _uv_area(corner_uvs: np.ndarray) -> float:
    a, b, c = corner_uvs[:, 0], corner_uvs[:, 1], corner_uvs[:, 2]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return float(0.5 * np.abs(cross).sum())


UvMesh = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""(position index per vertex, vertex positions, vertex uvs, faces) of a part with one uv per vertex."""


def _weld_corners(v: np.ndarray, f: np.ndarray, corner_uvs: np.ndarray) -> UvMesh:
    """One vertex per unique (position, uv) corner: a uv seam splits a position, nothing else does."""
    key = np.concatenate([f.reshape(-1, 1).astype(np.float64), corner_uvs.reshape(-1, 2)], axis=1)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    pos_id = uniq[:, 0].astype(np.int64)
    return pos_id, v[pos_id], uniq[:, 1:3], inverse.reshape(-1, 3)


def _xatlas_unwrap(v: np.ndarray, f: np.ndarray, options: PreprocessOptions) -> UvMesh:
    """A fresh chart atlas from xatlas (imported here: only parts without usable source uvs need it)."""
    import xatlas

    chart_options = xatlas.ChartOptions()
    chart_options.max_iterations = options.xatlas_iterations
    chart_options.max_chart_area = options.xatlas_max_chart_area
    atlas = xatlas.Atlas()
    atlas.add_mesh(v.astype(np.float32), f.astype(np.uint32))
    atlas.generate(chart_options, xatlas.PackOptions())
    vmapping, indices, atlas_uvs = atlas.get_mesh(0)
    pos_id = np.asarray(vmapping, np.int64)
    unwrapped = pos_id, v[pos_id], np.asarray(atlas_uvs, np.float64), np.asarray(indices, np.int64).reshape(-1, 3)
    _retire(atlas)
    return unwrapped


def _retire(atlas: Any) -> None:
    """Keep `atlas` alive until `RETIRED_ATLASES` newer ones exist and `RETIRED_SECONDS` have passed, then
    let the oldest go (see there); past `RETIRED_CAP` retired atlases, wait for the oldest's time."""
    with _retired_lock:
        _retired.append((time.monotonic(), atlas))
        if len(_retired) <= RETIRED_ATLASES:
            return
        retired_at, _ = _retired[0]
        wait = retired_at + RETIRED_SECONDS - time.monotonic()
        if wait > 0 and len(_retired) <= RETIRED_CAP:
            return
        _, oldest = _retired.popleft()
    if wait > 0:
        time.sleep(wait)
    del oldest  # destroyed here, outside the lock


def _finish_part(
    index: int, clean: _Clean, options: PreprocessOptions, warnings: list[str]
) -> PartMesh:
    """UVs (source, xatlas or box), crease normals, per-vertex arrays for one cleaned part."""
    v, f = clean.vertices, clean.faces
    uv_source = "source"
    corner_uv = clean.corner_uvs
    if corner_uv is not None and (not np.isfinite(corner_uv).all() or _uv_area(corner_uv) <= 1e-12):
        warnings.append(f"part {clean.raw.name!r}: source UVs are degenerate; regenerated")
        corner_uv = None
    if corner_uv is not None:
        pos_id, verts, uvs, faces = _weld_corners(v, f, corner_uv)
    elif len(f) <= options.xatlas_max_faces:
        pos_id, verts, uvs, faces = _xatlas_unwrap(v, f, options)
        uv_source = "xatlas"
    if corner_uv is None and (len(f) > options.xatlas_max_faces or not np.isfinite(uvs).all()):
        if len(f) <= options.xatlas_max_faces:  # xatlas gave NaN charts (seen on degenerate catalogue parts)
            warnings.append(f"part {clean.raw.name!r}: the UV unwrap failed; box-projected instead")
        pos_id, verts, uvs, faces = _weld_corners(v, f, _box_uvs(v, f))
        uv_source = "box"
    normals = corner_normals(verts, faces, pos_id, options.crease_angle_deg)
    src, new_faces, vertex_normals = split_vertices(faces, normals)
    material = clean.raw.material
    builtin: dict[str, Any] = {
        "albedo": [float(c) for c in material.albedo],
        "roughness": float(material.roughness),
        "metallic": float(material.metallic),
        "name": material.name,
    }
    meta: dict[str, Any] = dict(clean.raw.meta)
    meta["uv_source"] = uv_source
    meta["source_material"] = material.name
    if material.extra:
        meta["material_origin"] = material.extra.get("origin")
        if "opacity" in material.extra:
            builtin["opacity"] = material.extra["opacity"]
    return PartMesh(
        index=index,
        name=clean.raw.name,
        vertices=verts[src].astype(np.float32),
        faces=new_faces.astype(np.int32),
        normals=vertex_normals.astype(np.float32),
        uvs=uvs[src].astype(np.float32),
        builtin_material=builtin,
        meta=meta,
    )


def preprocess(raw: RawShape, options: PreprocessOptions | None = None) -> ShapeMesh:
    """RawShape -> ShapeMesh in the unit cube, or BadShapeError when nothing usable is left."""
    options = options or PreprocessOptions()
    warnings = list(raw.warnings)
    if not raw.parts or raw.num_faces == 0:
        raise BadShapeError("no faces")
    rotation = None
    if options.rotation is not None:
        rotation = np.asarray(options.rotation, np.float64).reshape(3, 3)
    parts: list[RawPart] = []
    for part in raw.parts:
        hidden = hidden_character(part.name)
        if hidden is not None:  # part names become keys and labels: checked like every other name
            raise BadShapeError(f"part name {one_line(part.name)!r} contains {hidden}")
        vertices = np.asarray(part.vertices, np.float64)
        if rotation is not None:
            vertices = vertices @ rotation.T
        used = np.unique(part.faces) if len(part.faces) else np.zeros(0, np.int64)
        if not np.isfinite(vertices[used]).all():
            raise BadShapeError(f"part {part.name!r}: non-finite vertex coordinates")
        if len(used) and float(np.abs(vertices[used]).max()) > MAX_COORDINATE:
            raise BadShapeError(f"part {part.name!r}: vertex coordinates beyond {MAX_COORDINATE:.0e} "
                                "(absurd scale; their extent would overflow)")
        parts.append(RawPart(part.name, vertices, part.faces, part.uvs, part.material, part.meta))
    allv = np.concatenate([p.vertices[np.unique(p.faces)] for p in parts if len(p.faces)])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if not np.isfinite(diag) or diag <= 0:
        raise BadShapeError("zero-size bounding box (all vertices coincide)")
    cleaned: list[_Clean] = []
    dropped: list[str] = []
    for part in parts:
        clean = _weld(part, options.merge_tolerance * diag, options.degenerate_area * diag * diag)
        if len(clean.faces) == 0:
            dropped.append(part.name)
            continue
        cleaned.append(clean)
    if not cleaned:
        raise BadShapeError("no faces left after removing degenerate triangles")
    if dropped:
        warnings.append(f"parts without usable faces dropped: {', '.join(dropped)}")
    # unit cube: centre the bounding box, longest side 1
    allv = np.concatenate([c.vertices for c in cleaned])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    extent = float((hi - lo).max())
    if extent <= 0:
        raise BadShapeError("zero-size bounding box after cleaning")
    centre = (lo + hi) / 2.0
    scale = 1.0 / extent
    for clean in cleaned:
        clean.vertices = (clean.vertices - centre) * scale
    out_parts = [_finish_part(i + 1, clean, options, warnings) for i, clean in enumerate(cleaned)]
    meta: dict[str, Any] = dict(raw.meta)
    meta["normalization"] = {"centre": [float(c) for c in centre], "scale": scale}
    meta["preprocess"] = options.as_dict()
    if dropped:
        meta["dropped_parts"] = dropped
    if warnings:
        meta["warnings"] = warnings
    return ShapeMesh(parts=out_parts, meta=meta)
