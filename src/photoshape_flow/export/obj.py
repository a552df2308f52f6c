"""Wavefront OBJ + MTL for legacy tools, textures copied beside them.

One ``o``/``g`` group and one ``usemtl`` per part (the part's name), texcoords with the renderer's UV
transform baked in (see `export.geometry`), OBJ's own v-up convention. The MTL carries:

- ``Kd`` (linear base colour; 1 1 1 under a texture, or a refinement's tint, which MTL readers
  multiply with the map) and ``map_Kd`` (the sRGB albedo); a refinement's UV scale and rotation are
  baked into the texcoords (MTL's ``-s`` has no rotation, and not every reader honours it);
- the PBR extension of MTL (tinyobjloader, Blender 3.5+ importer): ``Pr``/``map_Pr`` roughness,
  ``Pm``/``map_Pm`` metallic (the scalar is the map's mean, for readers that ignore the map),
  ``norm`` for the OpenGL-convention normal map, also written as ``map_Bump -bm 1`` because that
  is where Blender's exporter and importer put normal maps;
- ``Ns`` derived from roughness for viewers without PBR: Ns = 2/alpha^2 - 2 with alpha =
  roughness^2 (the Blinn-Phong exponent of the same lobe width), clamped to 0..1000;
- specular and height maps are copied and named in comments (no portable MTL statement).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photoshape_flow.export.geometry import export_parts
from photoshape_flow.export.pbr import PbrMaterial, ResolveRef, content_file_name, pbr_materials
from photoshape_flow.export.text import one_line, safe_name


def _comment(text: object) -> str:
    """A comment line whose text cannot end it (`export.text.one_line`): metadata stays inert."""
    return f"# {one_line(text)}"


def _ns(roughness: float) -> float:
    alpha = max(1e-3, min(1.0, roughness)) ** 2
    return max(0.0, min(1000.0, 2.0 / alpha**2 - 2.0))


def write_obj(
    path: str | Path,
    shape: Any,
    materials: Sequence[Any] | None = None,
    uv_transforms: Sequence[Any] | None = None,
    *,
    resolve_ref: ResolveRef | None = None,
    texture_dir: str = "textures",
    max_texture_size: int | None = None,
    header: Sequence[str] = (),
    content_names: bool = False,
) -> list[Path]:
    """Write `<stem>.obj`, `<stem>.mtl` and the textures; returns every file written.

    `header` lines (licences, attribution) go into both files as comments, each kept on its line.
    `content_names`: textures are named by their bytes (`pbr.content_file_name`), for a texture
    folder shared with other formats (`texture_dir` may then be ``../textures``).
    """
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    parts = export_parts(shape, materials, uv_transforms)
    pbr = pbr_materials(shape, list(materials) if materials is not None else None,
                        resolve_ref=resolve_ref, max_texture_size=max_texture_size)
    by_index = {p.index: m for p, m in zip(shape.parts, pbr, strict=True)}

    names: dict[int, str] = {}  # id(material) -> unique MTL name
    files: dict[str, bytes] = {}
    mtl_lines = [_comment(line) for line in ("photoshape_flow MTL export", *header)]
    for part in parts:
        mat = by_index[part.index]
        if id(mat) in names:
            continue
        name = safe_name(mat.name)
        while name in names.values():
            name = f"{name}_{len(names)}"
        names[id(mat)] = name
        mtl_lines += ["", *_mtl_entry(mat, name, texture_dir, files, content_names)]

    mtl_path = out.with_suffix(".mtl")
    obj_lines = [_comment(line) for line in ("photoshape_flow OBJ export", *header)]
    obj_lines.append(f"mtllib {mtl_path.name}")
    offset = 1
    for part in parts:
        name = safe_name(part.name)
        obj_lines += [f"o {name}", f"g {name}"]
        obj_lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in part.positions.tolist()]
        obj_lines += [f"vt {u:.7g} {v:.7g}" for u, v in part.texcoords.tolist()]
        obj_lines += [f"vn {x:.7g} {y:.7g} {z:.7g}" for x, y, z in part.normals.tolist()]
        obj_lines.append(f"usemtl {names[id(by_index[part.index])]}")
        for a, b, c in (part.faces.astype("int64") + offset).tolist():
            obj_lines.append(f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}")
        offset += len(part.positions)

    written = [out, mtl_path]
    out.write_text("\n".join(obj_lines) + "\n")
    mtl_path.write_text("\n".join(mtl_lines) + "\n")
    for rel, data in files.items():
        target = out.parent / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
        written.append(target)
    return written


def _mtl_entry(mat: PbrMaterial, name: str, texture_dir: str, files: dict[str, bytes],
               content_names: bool = False) -> list[str]:
    def put(kind: str, data: bytes, ext: str) -> str:
        ext = safe_name(ext, "png")
        # one token; ../ only where the caller asked for a shared folder
        file_name = content_file_name(data, ext) if content_names else f"{name}_{safe_name(kind, 'map')}.{ext}"
        rel = f"{texture_dir}/{file_name}"
        files[rel] = data
        return rel

    r, g, b, _ = mat.base_color_factor
    rough = _channel_mean(mat, 1, mat.roughness_factor)
    lines = [
        f"newmtl {name}",
        "Ka 0 0 0",
        f"Kd {r:.6f} {g:.6f} {b:.6f}",
        "Ks 0.04 0.04 0.04",
        f"Ns {_ns(rough):.3f}",
        "illum 2",
        f"Pr {rough:.6f}",
        f"Pm {_metallic(mat):.6f}",
    ]
    if mat.substance:
        lines.insert(1, _comment(f"substance: {mat.substance}"))
    if mat.base_color is not None:
        lines.append(f"map_Kd {put('basecolor', mat.base_color.data, mat.base_color.ext)}")
    if mat.roughness is not None:
        lines.append(f"map_Pr {put('roughness', mat.roughness.data, 'png')}")
    if mat.metallic is not None:
        lines.append(f"map_Pm {put('metallic', mat.metallic.data, 'png')}")
    if mat.normal is not None:
        rel = put("normal", mat.normal.data, "png")
        lines += ["# normal map, OpenGL convention (+Y green)", f"norm {rel}", f"map_Bump -bm 1 {rel}"]
    for channel, source in sorted(mat.extra_maps.items()):
        data = Path(source).read_bytes()
        rel = put(channel, data, Path(source).suffix.lstrip(".").lower() or "png")
        lines.append(_comment(f"{channel} map (linear; no portable MTL statement): {rel}"))
    return lines


def _channel_mean(mat: PbrMaterial, index: int, factor: float) -> float:
    """Mean of an ORM channel (1 = roughness, 2 = metallic) times its factor: the scalar MTL value."""
    import cv2
    import numpy as np

    if mat.orm is None:
        return factor
    array = cv2.imdecode(np.frombuffer(mat.orm.data, np.uint8), cv2.IMREAD_COLOR)  # BGR
    return factor * float(array[..., 2 - index].mean()) / 255.0


def _metallic(mat: PbrMaterial) -> float:
    return _channel_mean(mat, 2, mat.metallic_factor)
