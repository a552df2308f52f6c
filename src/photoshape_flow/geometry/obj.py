"""A defensive Wavefront OBJ + MTL reader: material groups become parts, nothing can crash it.

Own parser rather than a library because real furniture OBJs are messy (polygons, negative indices,
missing MTL files, Java3D colour names without an MTL, truncated files, Windows paths) and some crash
other importers. It reads positions, texture coordinates, faces, `g`/`o` groups and `usemtl`;
polygons are fan-triangulated; vertex normals are ignored (preprocessing recomputes them). Limits
(faces) are enforced while reading so an absurd file fails fast instead of exhausting memory.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from photoshape_flow.geometry.raw import BadShapeError, RawMaterial, RawPart, RawShape, ShapeTooLargeError

DEFAULT_MATERIAL = "default"

# Kd (sRGB 0..1) and Ns of Java3D's default materials, which Sweet Home 3D OBJ files name with
# `usemtl` and no `mtllib` (values from com.sun.j3d.loaders.objectfile.DefaultMaterials).
JAVA3D_MATERIALS: dict[str, tuple[tuple[float, float, float], float | None]] = {
    "amber": ((0.5755, 0.2678, 0.0), 60.0),
    "charcoal": ((0.0041, 0.0041, 0.0041), 60.0),
    "white": ((1.0, 1.0, 1.0), 60.0),
    "red": ((0.7714, 0.0, 0.0), 136.43),
    "grey": ((0.1837, 0.1837, 0.1837), 65.89),
    "black": ((0.002, 0.002, 0.002), 157.36),
    "silver": ((0.6163, 0.6163, 0.6163), 60.0),
    "brown": ((0.0857, 0.0147, 0.0), 65.89),
    "ltbrown": ((0.2776, 0.1143, 0.0531), 60.0),
    "tan": ((0.6612, 0.5221, 0.2186), 60.0),
    "glass": ((0.4873, 0.4919, 0.5306), 200.0),
    "gold": ((1.0, 0.4898, 0.0), 123.26),
    "brass": ((0.4776, 0.1959, 0.0), 134.88),
    "bone": ((0.9, 0.7626, 0.4261), 200.0),
    "taupe": ((0.2041, 0.1227, 0.1058), 84.5),
    "dkgrey": ((0.049, 0.049, 0.049), 60.0),
    "dkdkgrey": ((0.0122, 0.0122, 0.0122), 60.0),
    "dkgreen": ((0.0058, 0.0245, 0.0), 60.0),
    "dkblue": ((0.0, 0.0041, 0.0571), 60.0),
    "dkred": ((0.2286, 0.0, 0.0), 60.0),
    "dkteal": ((0.0, 0.0653, 0.0449), 55.04),
    "yellow": ((1.0, 0.6667, 0.0), 65.89),
    "orange": ((1.0, 0.1667, 0.0), 65.89),
    "purple": ((0.5, 0.0, 1.0), 65.89),
    "green": ((0.0, 0.25, 0.0), 65.89),
    "lime": ((0.0, 1.0, 0.0), 65.89),
    "blue_pure": ((0.0, 0.0, 1.0), 65.89),
    "navy_blue": ((0.0, 0.0, 0.0531), 91.47),
    "redwood": ((0.2571, 0.033, 0.0), 91.47),
    "pale_yellow": ((0.6898, 0.6211, 0.1999), 91.47),
    "rubber": ((0.01, 0.01, 0.01), 65.89),
    "flaqua": ((0.0, 0.5, 0.5), None),
    "flblack": ((0.0041, 0.0041, 0.0041), None),
    "flblue_pure": ((0.0, 0.0, 0.7102), None),
    "flgrey": ((0.5, 0.5, 0.5), None),
    "fllime": ((0.0, 1.0, 0.0), None),
    "florange": ((1.0, 0.1667, 0.0), None),
    "flpurple": ((0.3755, 0.0, 0.751), None),
    "flred": ((1.0, 0.0, 0.0), None),
    "flyellow": ((1.0, 0.6667, 0.0), None),
    "flbrown": ((0.1102, 0.012, 0.0013), None),
    "fldkblue_pure": ((0.0, 0.0, 0.1347), None),
    "fldkgreen": ((0.0058, 0.0245, 0.0), None),
    "fldkdkgrey": ((0.0122, 0.0122, 0.0122), None),
    "flltbrown": ((0.2776, 0.1143, 0.0531), None),
    "fltan": ((0.6612, 0.4567, 0.1295), None),
    "flblonde": ((0.5714, 0.3283, 0.0443), None),
    "flltgrey": ((0.8245, 0.8245, 0.8245), None),
    "offwhite.warm": ((0.8367, 0.6898, 0.449), 60.0),
    "offwhite.cool": ((0.8367, 0.6812, 0.5703), 60.0),
    "archwhite": ((0.9959, 0.9959, 0.9959), None),
}

_MAP_OPTION_ARGS = {  # MTL texture options and how many arguments they take (at most)
    "-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
    "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1,
}


def roughness_from_ns(ns: float) -> float:
    """Blinn-Phong exponent to microfacet roughness, sqrt(2 / (Ns + 2)) as the original code."""
    ns = max(float(ns), 0.0)
    return float(math.sqrt(2.0 / (ns + 2.0)))


@dataclass
class MtlMaterial:
    name: str
    kd: tuple[float, float, float] | None = None
    ns: float | None = None
    pr: float | None = None  # PBR extension: roughness
    pm: float | None = None  # PBR extension: metallic
    opacity: float | None = None
    map_kd: str | None = None
    base: Path | None = None  # folder of the MTL file (texture names are relative to it)
    extra: dict[str, str] = field(default_factory=dict)


def _floats(tokens: list[str], count: int) -> list[float] | None:
    try:
        values = [float(t) for t in tokens[:count]]
    except ValueError:
        return None
    if len(values) < count or not all(math.isfinite(v) for v in values):
        return None
    return values


def texture_filename(tokens: list[str]) -> str | None:
    """The file name of a `map_*` statement after its options (may contain spaces)."""
    i = 0
    while i < len(tokens) and tokens[i].lower() in _MAP_OPTION_ARGS:
        wanted = _MAP_OPTION_ARGS[tokens[i].lower()]
        i += 1
        taken = 0
        while taken < wanted and i < len(tokens) - 1:
            if wanted > 1 and taken >= 1 and not _is_number(tokens[i]):
                break
            i += 1
            taken += 1
    name = " ".join(tokens[i:]).strip().strip('"')
    return name.replace("\\", "/") or None


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def parse_mtl(text: str) -> dict[str, MtlMaterial]:
    """Materials of an MTL file by name; unknown statements are kept in `extra`."""
    materials: dict[str, MtlMaterial] = {}
    current: MtlMaterial | None = None
    for raw_line in text.splitlines():
        line = raw_line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        key, args = parts[0], parts[1:]
        lower = key.lower()
        if lower == "newmtl":
            name = " ".join(args) or DEFAULT_MATERIAL
            current = materials.setdefault(name, MtlMaterial(name))
            continue
        if current is None:
            continue
        if lower == "kd":
            rgb = _floats(args, 3)
            if rgb is None and (one := _floats(args, 1)) is not None:
                rgb = one * 3
            if rgb is not None:
                current.kd = (rgb[0], rgb[1], rgb[2])
        elif lower == "ns" and (v := _floats(args, 1)):
            current.ns = v[0]
        elif lower == "pr" and (v := _floats(args, 1)):
            current.pr = v[0]
        elif lower == "pm" and (v := _floats(args, 1)):
            current.pm = v[0]
        elif lower == "d" and (v := _floats(args, 1)):
            current.opacity = v[0]
        elif lower == "tr" and (v := _floats(args, 1)):
            current.opacity = 1.0 - v[0]
        elif lower == "map_kd":
            current.map_kd = texture_filename(args)
        else:
            current.extra[key] = " ".join(args)
    return materials


def _clip01(value: float) -> float:
    return float(min(max(value, 0.0), 1.0))


def raw_material(name: str, mtl: MtlMaterial | None, texture: Path | None) -> RawMaterial:
    """A part's built-in material: MTL values, else Java3D's named defaults, else light grey."""
    extra: dict[str, object] = {}
    if mtl is not None:
        kd = mtl.kd if mtl.kd is not None else (0.8, 0.8, 0.8)
        if mtl.pr is not None:
            roughness = _clip01(mtl.pr)
        else:
            roughness = roughness_from_ns(mtl.ns if mtl.ns is not None else 0.0)
        metallic = _clip01(mtl.pm) if mtl.pm is not None else 0.0
        if mtl.opacity is not None:
            extra["opacity"] = _clip01(mtl.opacity)
        extra["origin"] = "mtl"
    elif name.lower() in JAVA3D_MATERIALS:
        kd, ns = JAVA3D_MATERIALS[name.lower()]
        roughness = roughness_from_ns(ns or 0.0)
        metallic = 0.0
        extra["origin"] = "java3d-default"
    else:
        kd, roughness, metallic = (0.8, 0.8, 0.8), 1.0, 0.0
        extra["origin"] = "fallback"
    albedo = (_clip01(kd[0]), _clip01(kd[1]), _clip01(kd[2]))
    return RawMaterial(name=name, albedo=albedo, roughness=roughness, metallic=metallic,
                       texture_path=texture, extra=extra)


def resolve_inside(base: Path, relative: str, root: Path) -> Path | None:
    """`relative` resolved against `base`, case-insensitively if needed; None if missing or outside `root`."""
    relative = relative.replace("\\", "/").strip()
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


def mtl_references(text: str) -> list[str]:
    """Texture file names referenced by `map_*`/`bump`/`disp`/`norm` statements of an MTL."""
    names: list[str] = []
    for line in text.splitlines():
        parts = line.strip().split()
        if parts and (parts[0].lower().startswith("map_") or parts[0].lower() in ("bump", "disp", "norm", "refl")):
            name = texture_filename(parts[1:])
            if name:
                names.append(name)
    return names


def decode_text(data: bytes, label: str) -> str:
    """OBJ/MTL bytes to text; binary content is rejected rather than parsed as garbage."""
    head = data[:65536]
    if b"\x00" in head:
        raise BadShapeError(f"{label}: binary content, not a text OBJ/MTL file")
    return data.decode("utf-8", errors="replace")


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
    warnings: list[str] = []

    positions: list[tuple[float, float, float]] = []
    texcoords: list[tuple[float, float]] = []
    # per material: lists of (v, vt) corner triplets and the group of each face
    order: list[str] = []
    face_v: dict[str, list[tuple[int, int, int]]] = {}
    face_t: dict[str, list[tuple[int, int, int]]] = {}
    face_group: dict[str, list[int]] = {}
    groups: list[str] = []
    group_index: dict[str, int] = {}
    objects: list[str] = []
    mtllibs: list[str] = []
    current_material = DEFAULT_MATERIAL
    current_group = 0
    group_index["default"] = 0
    groups.append("default")
    total_faces = 0
    malformed = 0
    short_faces = 0

    def use_group(name: str) -> int:
        if name not in group_index:
            group_index[name] = len(groups)
            groups.append(name)
        return group_index[name]

    for line in text.splitlines():
        if not line or line[0] == "#":
            continue
        c0 = line[0]
        if c0 == "v":
            c1 = line[1:2]
            if c1 == " " or c1 == "\t":
                p = line.split()
                try:
                    positions.append((float(p[1]), float(p[2]), float(p[3])))
                except (ValueError, IndexError):
                    malformed += 1
                    positions.append((math.nan, math.nan, math.nan))
            elif c1 == "t":
                p = line.split()
                try:
                    u = float(p[1])
                    v = float(p[2]) if len(p) > 2 else 0.0
                    texcoords.append((u, v))
                except (ValueError, IndexError):
                    malformed += 1
                    texcoords.append((math.nan, math.nan))
            continue
        if c0 == "f":
            tokens = line.split()[1:]
            if len(tokens) < 3:
                short_faces += 1
                continue
            nv = len(positions)
            nt = len(texcoords)
            vi: list[int] = []
            ti: list[int] = []
            ok = True
            for tok in tokens:
                fields = tok.split("/")
                try:
                    a = int(fields[0])
                except ValueError:
                    ok = False
                    break
                vi.append(a - 1 if a > 0 else nv + a)
                if len(fields) > 1 and fields[1]:
                    try:
                        b = int(fields[1])
                    except ValueError:
                        b = 0
                    ti.append(b - 1 if b > 0 else (nt + b if b < 0 else -1))
                else:
                    ti.append(-1)
            if not ok:
                malformed += 1
                continue
            n = len(vi)
            total_faces += n - 2
            if max_faces is not None and total_faces > max_faces:
                raise ShapeTooLargeError(f"{path.name}: more than {max_faces} faces (limit)")
            if current_material not in face_v:
                order.append(current_material)
                face_v[current_material] = []
                face_t[current_material] = []
                face_group[current_material] = []
            fv, ft, fg = face_v[current_material], face_t[current_material], face_group[current_material]
            for k in range(1, n - 1):
                fv.append((vi[0], vi[k], vi[k + 1]))
                ft.append((ti[0], ti[k], ti[k + 1]))
                fg.append(current_group)
            continue
        if line.startswith("usemtl"):
            current_material = line[6:].strip() or DEFAULT_MATERIAL
        elif c0 == "g" and line[1:2] in (" ", "\t", ""):
            current_group = use_group(line[1:].strip() or "default")
        elif c0 == "o" and line[1:2] in (" ", "\t"):
            name = line[1:].strip()
            objects.append(name)
            current_group = use_group(name or "default")
        elif line.startswith("mtllib"):
            mtllibs.extend(obj_references(line))

    if total_faces == 0:
        raise BadShapeError(f"{path.name}: no faces")
    if malformed:
        warnings.append(f"{path.name}: {malformed} malformed lines skipped")
    if short_faces:
        warnings.append(f"{path.name}: {short_faces} faces with fewer than 3 vertices (edges) skipped")

    # materials
    mtl: dict[str, MtlMaterial] = {}
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
        mtl.update(parsed)

    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    tex = np.asarray(texcoords, np.float64).reshape(-1, 2)
    parts: list[RawPart] = []
    for name in order:
        fv = np.asarray(face_v[name], np.int64).reshape(-1, 3)
        ft = np.asarray(face_t[name], np.int64).reshape(-1, 3)
        if fv.min() < 0 or fv.max() >= len(pos):
            bad = int(fv.max()) + 1 if fv.max() >= len(pos) else int(fv.min()) + 1
            raise BadShapeError(
                f"{path.name}: face refers to vertex {bad} but the file defines {len(pos)} (truncated or corrupt)"
            )
        used = np.unique(fv)
        if not np.isfinite(pos[used]).all():
            raise BadShapeError(f"{path.name}: non-finite (NaN/inf or malformed) vertex coordinates")
        has_uv = bool((ft >= 0).all() and len(tex) > 0 and ft.max() < len(tex))
        if has_uv and not np.isfinite(tex[np.unique(ft)]).all():
            has_uv = False
            warnings.append(f"{path.name}: part {name!r} has non-finite UVs; they are regenerated")
        if has_uv:
            key = np.stack([fv.ravel(), ft.ravel()], axis=1)
            uniq, inverse = np.unique(key, axis=0, return_inverse=True)
            vertices = pos[uniq[:, 0]]
            uvs: np.ndarray | None = tex[uniq[:, 1]]
        else:
            uniq_v, inverse = np.unique(fv.ravel(), return_inverse=True)
            vertices = pos[uniq_v]
            uvs = None
        faces = inverse.reshape(-1, 3).astype(np.int64)
        group_ids, counts = np.unique(np.asarray(face_group[name], np.int64), return_counts=True)
        group_faces = {groups[g]: int(c) for g, c in zip(group_ids, counts, strict=True)}
        texture = None
        material = mtl.get(name)
        if material is not None and material.map_kd:
            texture = resolve_inside(material.base or path.parent, material.map_kd, root)
            if texture is None:
                warnings.append(f"{path.name}: texture {material.map_kd!r} of material {name!r} not found")
        parts.append(
            RawPart(
                name=name,
                vertices=vertices,
                faces=faces,
                uvs=uvs,
                material=raw_material(name, material, texture),
                meta={"groups": group_faces},
            )
        )
    used_groups = {g for p in parts for g in p.meta["groups"]}
    meta = {"source_format": "obj", "groups": [g for g in groups if g in used_groups], "materials": order}
    if objects:
        meta["objects"] = objects
    return RawShape(parts=parts, meta=meta, warnings=warnings)


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
