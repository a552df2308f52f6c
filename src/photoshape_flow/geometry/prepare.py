"""Read + preprocess one shape file into a `ShapeMesh` and its textures: the unit of isolated work.

`prepare_shape` is a plain top-level function of picklable arguments so it can run in a separate
process (`geometry.isolate`): native libraries (pymeshlab, xatlas, image decoders) may crash or hang
on hostile input, and such a crash must cost one item, not the batch. Textures come back as bytes
keyed by a placeholder that the caller swaps for a blob ref (`texture` in `builtin_material`).
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from photoshape_flow.geometry.gltf import parse_gltf
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.geometry.obj import parse_obj
from photoshape_flow.geometry.preprocess import PreprocessOptions, preprocess
from photoshape_flow.geometry.raw import BadShapeError, RawMaterial

TEXTURE_PLACEHOLDER = "texture:"
_KEEP_FORMATS = {"JPEG": "jpg", "PNG": "png", "WEBP": "webp"}


@dataclass
class PreparedShape:
    mesh: ShapeMesh
    textures: dict[str, tuple[bytes, str]] = field(default_factory=dict)  # placeholder -> (bytes, ext)
    warnings: list[str] = field(default_factory=list)


def _texture_bytes(material: RawMaterial, max_pixels: int) -> tuple[bytes, str]:
    """A texture as storable bytes: JPEG/PNG/WebP files as they are, anything else as PNG."""
    from PIL import Image

    if material.texture_path is not None:
        data = Path(material.texture_path).read_bytes()
        with Image.open(io.BytesIO(data)) as probe:
            width, height = probe.size
            if width * height > max_pixels:
                raise ValueError(f"{width}x{height} pixels (limit {max_pixels})")
            fmt = probe.format or ""
            if fmt in _KEEP_FORMATS:
                probe.verify()
                return data, _KEEP_FORMATS[fmt]
            probe.load()
            image = probe.convert("RGBA" if "A" in probe.getbands() else "RGB")
    else:
        image = material.texture_image
        if isinstance(image, np.ndarray):
            image = Image.fromarray(image)
        width, height = image.size
        if width * height > max_pixels:
            raise ValueError(f"{width}x{height} pixels (limit {max_pixels})")
        image = image.convert("RGBA" if "A" in image.getbands() else "RGB")
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue(), "png"


def prepare_shape(
    model: str,
    fmt: str,
    root: str,
    options: PreprocessOptions,
    max_faces: int | None = None,
    max_texture_pixels: int = 64 * 1024 * 1024,
) -> PreparedShape:
    """Parse `model` (obj | gltf | glb) and preprocess it; BadShapeError for unusable input."""
    path = Path(model)
    if fmt == "obj":
        raw = parse_obj(path, root=Path(root), max_faces=max_faces)
    elif fmt in ("gltf", "glb"):
        raw = parse_gltf(path, max_faces=max_faces)
    else:
        raise BadShapeError(f"{path.name}: unsupported format {fmt!r}")
    textures: dict[str, tuple[bytes, str]] = {}
    by_part: dict[str, str] = {}
    warnings: list[str] = []
    for part in raw.parts:
        material = part.material
        if material.texture_path is None and material.texture_image is None:
            continue
        try:
            data, ext = _texture_bytes(material, max_texture_pixels)
        except Exception as exc:  # unreadable texture: keep the part, drop its texture
            source = material.texture_path.name if material.texture_path is not None else "embedded image"
            warnings.append(f"texture {source} of material {material.name!r} dropped: {exc}")
            continue
        key = TEXTURE_PLACEHOLDER + hashlib.sha256(data).hexdigest()[:16]
        textures[key] = (data, ext)
        by_part[part.name] = key
    mesh = preprocess(raw, options)
    for part in mesh.parts:
        if part.name in by_part:
            part.builtin_material["texture"] = by_part[part.name]
    if warnings:
        mesh.meta.setdefault("warnings", []).extend(warnings)
    return PreparedShape(mesh=mesh, textures=textures, warnings=list(mesh.meta.get("warnings", [])))
