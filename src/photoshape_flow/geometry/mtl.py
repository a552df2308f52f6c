"""Wavefront MTL reading: material statements, texture names, and a part's built-in material.

Real MTL files are as messy as the OBJs that name them (texture options before file names, names
with spaces or Windows separators, Java3D colour names with no MTL at all), so everything here is
lenient: unknown statements are kept, unparsable values are skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from photoshape_flow.geometry.raw import RawMaterial

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
