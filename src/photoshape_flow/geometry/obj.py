"""A defensive Wavefront OBJ reader: material groups become parts, nothing can crash it.

Own parser rather than a library because real furniture OBJs are messy (polygons, negative indices,
missing MTL files, Java3D colour names without an MTL, truncated files, Windows paths) and some crash
other importers. It reads positions, texture coordinates, faces, `g`/`o` groups and `usemtl`;
polygons are fan-triangulated; vertex normals are ignored (preprocessing recomputes them). Limits
(faces) are enforced while reading so an absurd file fails fast instead of exhausting memory. The
MTL side (materials, textures, built-in colours) is `geometry.mtl`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from photoshape_flow.geometry.mtl import DEFAULT_MATERIAL, MtlMaterial, mtl_references, parse_mtl, raw_material
from photoshape_flow.geometry.raw import BadShapeError, RawPart, RawShape, ShapeTooLargeError


def resolve_inside(base: Path, relative: str, root: Path) -> Path | None:
    """`relative` resolved against `base`, case-insensitively if needed; None if missing or outside `root`."""
    relative = relative.replace("\\", "/").strip()
    if "\0" in relative:  # no file name holds a NUL; os calls would raise ValueError on it
        return None
    if not relative or relative.startswith("/") or re.match(r"^[A-Za-z]:", relative):
        # absolute paths from the author's machine: try the file name next to the model
        relative = relative.rsplit("/", 1)[-1]
        if not relative:
            return None
    candidate = (base / relative).resolve()
    root = root.resolve()
    if not candidate.is_relative_to(root):
        return None
    if candidate.is_file():
        return candidate
    parent = candidate.parent
    if parent.is_dir():
        wanted = candidate.name.lower()
        for entry in parent.iterdir():
            if entry.name.lower() == wanted and entry.is_file():
                return entry
    return None


def obj_references(text: str) -> list[str]:
    """The `mtllib` file names of an OBJ text (each statement may name several files)."""
    names: list[str] = []
    for line in text.splitlines():
        if line.startswith("mtllib"):
            rest = line[6:].strip()
            if not rest:
                continue
            # names may contain spaces when there is only one; otherwise split on whitespace
            names.extend([rest] if rest.lower().endswith(".mtl") and rest.count(".mtl") == 1 else rest.split())
    return names


def decode_text(data: bytes, label: str) -> str:
    """OBJ/MTL bytes to text; binary content is rejected rather than parsed as garbage."""
    head = data[:65536]
    if b"\x00" in head:
        raise BadShapeError(f"{label}: binary content, not a text OBJ/MTL file")
    return data.decode("utf-8", errors="replace")


@dataclass
class _MaterialFaces:
    """The triangles of one `usemtl` material: (v, v, v) and (vt, vt, vt) corners and each one's group."""

    vertices: list[tuple[int, int, int]] = field(default_factory=list)
    texcoords: list[tuple[int, int, int]] = field(default_factory=list)
    groups: list[int] = field(default_factory=list)


@dataclass
class _ObjContent:
    """What an OBJ's statements declare, accumulated line by line, and the reading state."""

    positions: list[tuple[float, float, float]] = field(default_factory=list)
    texcoords: list[tuple[float, float]] = field(default_factory=list)
    faces: dict[str, _MaterialFaces] = field(default_factory=dict)  # by material, in order of first use
    groups: list[str] = field(default_factory=lambda: ["default"])
    group_index: dict[str, int] = field(default_factory=lambda: {"default": 0})
    objects: list[str] = field(default_factory=list)
    mtllibs: list[str] = field(default_factory=list)
    material: str = DEFAULT_MATERIAL  # the current `usemtl`
    group: int = 0  # the current `g` / `o`
    total_faces: int = 0
    malformed: int = 0
    short_faces: int = 0

    def use_group(self, name: str) -> int:
        if name not in self.group_index:
            self.group_index[name] = len(self.groups)
            self.groups.append(name)
        return self.group_index[name]


def parse_obj(
    path: Path,
    *,
    root: Path | None = None,
    max_faces: int | None = None,
    text: str | None = None,
) -> RawShape:
    """Read an OBJ (and its MTL files and textures inside `root`) into material-group parts.

    Parts are numbered in the order their `usemtl` name first appears; faces before any `usemtl`
    form a part named "default". Raises BadShapeError for files that cannot become a shape.
    """
    path = Path(path)
    root = Path(root) if root is not None else path.parent
    if text is None:
        text = decode_text(path.read_bytes(), path.name)
    content = _read_statements(text, path.name, max_faces)
    warnings = _reading_warnings(content, path.name)
    materials = _load_materials(content.mtllibs, path, root, warnings)
    pos = np.asarray(content.positions, np.float64).reshape(-1, 3)
    tex = np.asarray(content.texcoords, np.float64).reshape(-1, 2)
    parts = [
        _build_part(name, faces, pos, tex, content.groups, materials.get(name), path, root, warnings)
        for name, faces in content.faces.items()
    ]
    used_groups = {g for p in parts for g in p.meta["groups"]}
    order = list(content.faces)
    meta = {"source_format": "obj", "groups": [g for g in content.groups if g in used_groups], "materials": order}
    if content.objects:
        meta["objects"] = content.objects
    return RawShape(parts=parts, meta=meta, warnings=warnings)


def _read_statements(text: str, label: str, max_faces: int | None) -> _ObjContent:
    """Every statement of the OBJ text, in one pass; comments and unknown statements are skipped."""
    content = _ObjContent()
    for line in text.splitlines():
        if not line or line[0] == "#":
            continue
        c0 = line[0]
        if c0 == "v":
            _read_vertex(content, line)
        elif c0 == "f":
            _read_face(content, line, label, max_faces)
        else:
            _read_state(content, line)
    return content


def _read_vertex(content: _ObjContent, line: str) -> None:
    """A `v` position or `vt` texture coordinate; a malformed one is kept as NaN so indices stay valid."""
    c1 = line[1:2]
    if c1 == " " or c1 == "\t":
        p = line.split()
        try:
            content.positions.append((float(p[1]), float(p[2]), float(p[3])))
        except (ValueError, IndexError):
            content.malformed += 1
            content.positions.append((math.nan, math.nan, math.nan))
    elif c1 == "t":
        p = line.split()
        try:
            u = float(p[1])
            v = float(p[2]) if len(p) > 2 else 0.0
            content.texcoords.append((u, v))
        except (ValueError, IndexError):
            content.malformed += 1
            content.texcoords.append((math.nan, math.nan))


def _face_indices(tokens: list[str], nv: int, nt: int) -> tuple[list[int], list[int]] | None:
    """0-based vertex and texcoord indices of a face's corners (-1: no texcoord); None if malformed.

    Negative (relative) indices count back from the `nv` positions and `nt` texcoords read so far.
    """
    vi: list[int] = []
    ti: list[int] = []
    for tok in tokens:
        fields = tok.split("/")
        try:
            a = int(fields[0])
        except ValueError:
            return None
        vi.append(a - 1 if a > 0 else nv + a)
        if len(fields) > 1 and fields[1]:
            try:
                b = int(fields[1])
            except ValueError:
                b = 0
            ti.append(b - 1 if b > 0 else (nt + b if b < 0 else -1))
        else:
            ti.append(-1)
    return vi, ti


def _read_face(content: _ObjContent, line: str, label: str, max_faces: int | None) -> None:
    """An `f` statement, fan-triangulated into the current material with the current group."""
    tokens = line.split()[1:]
    if len(tokens) < 3:
        content.short_faces += 1
        return
    indices = _face_indices(tokens, len(content.positions), len(content.texcoords))
    if indices is None:
        content.malformed += 1
        return
    vi, ti = indices
    n = len(vi)
    content.total_faces += n - 2
    if max_faces is not None and content.total_faces > max_faces:
        raise ShapeTooLargeError(f"{label}: more than {max_faces} faces (limit)")
    faces = content.faces.get(content.material)
    if faces is None:
        faces = content.faces[content.material] = _MaterialFaces()
    for k in range(1, n - 1):
        faces.vertices.append((vi[0], vi[k], vi[k + 1]))
        faces.texcoords.append((ti[0], ti[k], ti[k + 1]))
        faces.groups.append(content.group)


def _read_state(content: _ObjContent, line: str) -> None:
    """`usemtl`, `g`, `o` and `mtllib`: the statements that set what the following faces belong to."""
    c0 = line[0]
    if line.startswith("usemtl"):
        content.material = line[6:].strip() or DEFAULT_MATERIAL
    elif c0 == "g" and line[1:2] in (" ", "\t", ""):
        content.group = content.use_group(line[1:].strip() or "default")
    elif c0 == "o" and line[1:2] in (" ", "\t"):
        name = line[1:].strip()
        content.objects.append(name)
        content.group = content.use_group(name or "default")
    elif line.startswith("mtllib"):
        content.mtllibs.extend(obj_references(line))


def _reading_warnings(content: _ObjContent, label: str) -> list[str]:
    """The warnings of the reading pass; a file without faces is no shape."""
    if content.total_faces == 0:
        raise BadShapeError(f"{label}: no faces")
    warnings: list[str] = []
    if content.malformed:
        warnings.append(f"{label}: {content.malformed} malformed lines skipped")
    if content.short_faces:
        warnings.append(f"{label}: {content.short_faces} faces with fewer than 3 vertices (edges) skipped")
    return warnings


def _load_materials(mtllibs: list[str], path: Path, root: Path, warnings: list[str]) -> dict[str, MtlMaterial]:
    """The materials of the OBJ's MTL files (later files win); a missing or unreadable file is a warning."""
    materials: dict[str, MtlMaterial] = {}
    for name in mtllibs:
        mtl_path = resolve_inside(path.parent, name, root)
        if mtl_path is None:
            warnings.append(f"{path.name}: material library {name!r} not found")
            continue
        try:
            parsed = parse_mtl(decode_text(mtl_path.read_bytes(), mtl_path.name))
        except (OSError, BadShapeError) as exc:
            warnings.append(f"{mtl_path.name}: unreadable material library ({exc})")
            continue
        for material in parsed.values():
            material.base = mtl_path.parent
        materials.update(parsed)
    return materials


def _part_geometry(
    name: str, faces: _MaterialFaces, pos: np.ndarray, tex: np.ndarray, label: str, warnings: list[str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A material's own (vertices, faces, uvs): only the corners it uses, one vertex per distinct
    (position, texcoord) pair when every corner has a finite texcoord, else UVs None (regenerated)."""
    fv = np.asarray(faces.vertices, np.int64).reshape(-1, 3)
    ft = np.asarray(faces.texcoords, np.int64).reshape(-1, 3)
    if fv.min() < 0 or fv.max() >= len(pos):
        bad = int(fv.max()) + 1 if fv.max() >= len(pos) else int(fv.min()) + 1
        raise BadShapeError(
            f"{label}: face refers to vertex {bad} but the file defines {len(pos)} (truncated or corrupt)"
        )
    used = np.unique(fv)
    if not np.isfinite(pos[used]).all():
        raise BadShapeError(f"{label}: non-finite (NaN/inf or malformed) vertex coordinates")
    has_uv = bool((ft >= 0).all() and len(tex) > 0 and ft.max() < len(tex))
    if has_uv and not np.isfinite(tex[np.unique(ft)]).all():
        has_uv = False
        warnings.append(f"{label}: part {name!r} has non-finite UVs; they are regenerated")
    if has_uv:
        key = np.stack([fv.ravel(), ft.ravel()], axis=1)
        uniq, inverse = np.unique(key, axis=0, return_inverse=True)
        vertices = pos[uniq[:, 0]]
        uvs: np.ndarray | None = tex[uniq[:, 1]]
    else:
        uniq_v, inverse = np.unique(fv.ravel(), return_inverse=True)
        vertices = pos[uniq_v]
        uvs = None
    return vertices, inverse.reshape(-1, 3).astype(np.int64), uvs


def _build_part(
    name: str,
    faces: _MaterialFaces,
    pos: np.ndarray,
    tex: np.ndarray,
    groups: list[str],
    material: MtlMaterial | None,
    path: Path,
    root: Path,
    warnings: list[str],
) -> RawPart:
    """One part: its geometry, face counts per group, and its built-in material with its texture."""
    vertices, tri, uvs = _part_geometry(name, faces, pos, tex, path.name, warnings)
    group_ids, counts = np.unique(np.asarray(faces.groups, np.int64), return_counts=True)
    group_faces = {groups[g]: int(c) for g, c in zip(group_ids, counts, strict=True)}
    texture = None
    if material is not None and material.map_kd:
        texture = resolve_inside(material.base or path.parent, material.map_kd, root)
        if texture is None:
            warnings.append(f"{path.name}: texture {material.map_kd!r} of material {name!r} not found")
    return RawPart(
        name=name,
        vertices=vertices,
        faces=tri,
        uvs=uvs,
        material=raw_material(name, material, texture),
        meta={"groups": group_faces},
    )


def referenced_files(obj_path: Path, root: Path, text: str | None = None) -> list[Path]:
    """The MTL files and textures an OBJ uses (inside `root`), for content hashing."""
    if text is None:
        text = obj_path.read_bytes().decode("utf-8", errors="replace")
    found: list[Path] = []
    for name in _mtllib_lines(text):
        mtl_path = resolve_inside(obj_path.parent, name, root)
        if mtl_path is None:
            continue
        found.append(mtl_path)
        try:
            mtl_text = mtl_path.read_bytes().decode("utf-8", errors="replace")
        except OSError:
            continue
        for tex in mtl_references(mtl_text):
            tex_path = resolve_inside(mtl_path.parent, tex, root)
            if tex_path is not None:
                found.append(tex_path)
    unique: dict[Path, None] = dict.fromkeys(found)
    return list(unique)


def _mtllib_lines(text: str) -> Iterable[str]:
    for line in text.splitlines():
        if line.startswith("mtllib"):
            yield from obj_references(line)
