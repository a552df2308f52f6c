"""glTF 2.0 writer (binary .glb or .gltf + .bin + textures), by hand with struct and json.

Layout: one scene with a root node (the PhotoShape) whose children are the parts, one mesh with one
triangle primitive per part (POSITION, NORMAL, TEXCOORD_0, uint32 indices). Materials use the core
metallic-roughness model (see `export.pbr`): baseColor texture in sRGB, ORM texture linear with
roughness in G and metallic in B, OpenGL-convention normal map. Texcoords carry the renderer's UV
transform baked in (see `export.geometry` for why not KHR_texture_transform), samplers repeat; a
refined material's UV scale and rotation (`fit.refine`) are the exception: KHR_texture_transform on
each of its textures (listed in ``extensionsUsed``, not required: a viewer without it shows the
library's tiling), and its tint and roughness scale are in its factors (`export.pbr`).
Primitives with a normal map get a TANGENT attribute built from the baked UVs the way Mitsuba's
`normalmap` frame is (dP/du), so viewers need not guess one (the validator warns when they must).
Metadata (licences, assignment) goes into ``asset.extras`` and ``asset.copyright``, and names into
``name``, each string on one line without control characters (`export.text`). The output
passes the Khronos validator (`export.validate.validate_gltf`).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.export.geometry import export_parts, gltf_texcoords, khr_texture_transform, tangents
from photoshape_flow.export.pbr import EncodedImage, PbrMaterial, ResolveRef, content_file_name, pbr_materials
from photoshape_flow.export.text import one_line, one_line_strings, safe_name

FLOAT, UINT32 = 5126, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
LINEAR, LINEAR_MIPMAP_LINEAR, REPEAT = 9729, 9987, 10497
GLB_MAGIC, JSON_CHUNK, BIN_CHUNK = 0x46546C67, 0x4E4F534A, 0x004E4942
KHR_TEXTURE_TRANSFORM = "KHR_texture_transform"


class _Builder:
    """Accumulates the binary buffer and the JSON arrays of a glTF document."""

    def __init__(self, embed_images: bool, texture_dir: str | None, content_names: bool = False):
        self.gltf: dict[str, Any] = {
            "asset": {"version": "2.0", "generator": "photoshape_flow"},
            "buffers": [], "bufferViews": [], "accessors": [], "meshes": [], "nodes": [],
            "materials": [], "textures": [], "images": [], "samplers": [], "scenes": [], "scene": 0,
        }
        self.blob = bytearray()
        self.embed_images = embed_images
        self.texture_dir = texture_dir
        self.content_names = content_names
        self.image_files: dict[str, bytes] = {}  # relative path -> bytes (non-embedded images)
        self._images: dict[str, int] = {}
        self._materials: dict[int, int] = {}

    def view(self, data: bytes, target: int | None = None) -> int:
        while len(self.blob) % 4:
            self.blob.append(0)
        entry: dict[str, Any] = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target is not None:
            entry["target"] = target
        self.blob.extend(data)
        self.gltf["bufferViews"].append(entry)
        return len(self.gltf["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int, bounds: bool = False) -> int:
        component = UINT32 if array.dtype == np.uint32 else FLOAT
        data = np.ascontiguousarray(array, dtype="<u4" if component == UINT32 else "<f4")
        entry: dict[str, Any] = {
            "bufferView": self.view(data.tobytes(), target),
            "componentType": component,
            "count": int(data.shape[0] if kind != "SCALAR" else data.size),
            "type": kind,
        }
        if bounds:
            entry["min"] = [float(x) for x in data.reshape(len(data), -1).min(axis=0)]
            entry["max"] = [float(x) for x in data.reshape(len(data), -1).max(axis=0)]
        self.gltf["accessors"].append(entry)
        return len(self.gltf["accessors"]) - 1

    def texture(self, image: EncodedImage, stem: str) -> int:
        key = image.digest
        if key not in self._images:
            entry: dict[str, Any] = {"name": stem}
            if self.embed_images:
                entry["bufferView"] = self.view(image.data)
                entry["mimeType"] = image.mime
            else:
                folder = f"{self.texture_dir}/" if self.texture_dir else ""
                file_name = content_file_name(image.data, image.ext) if self.content_names else f"{stem}.{image.ext}"
                rel = f"{folder}{file_name}"
                if rel in self.image_files:  # same name, other pixels (e.g. two built-ins)
                    rel = f"{folder}{stem}_{key[:8]}.{image.ext}"
                self.image_files[rel] = image.data
                entry["uri"] = rel
            self.gltf["images"].append(entry)
            if not self.gltf["samplers"]:
                self.gltf["samplers"].append(
                    {"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": REPEAT, "wrapT": REPEAT}
                )
            self.gltf["textures"].append({"sampler": 0, "source": len(self.gltf["images"]) - 1})
            self._images[key] = len(self.gltf["textures"]) - 1
        return self._images[key]

    def texture_info(self, mat: PbrMaterial, image: EncodedImage, stem: str) -> dict[str, Any]:
        """A textureInfo, with the material's refined UV transform as KHR_texture_transform when it has one."""
        info: dict[str, Any] = {"index": self.texture(image, stem)}
        if mat.uv_transform is not None:
            info["extensions"] = {KHR_TEXTURE_TRANSFORM: khr_texture_transform(*mat.uv_transform)}
            used = self.gltf.setdefault("extensionsUsed", [])
            if KHR_TEXTURE_TRANSFORM not in used:
                used.append(KHR_TEXTURE_TRANSFORM)
        return info

    def material(self, mat: PbrMaterial) -> int:
        if id(mat) in self._materials:
            return self._materials[id(mat)]
        stem = safe_name(mat.name)
        pbr: dict[str, Any] = {
            "baseColorFactor": [round(float(c), 6) for c in mat.base_color_factor],
            "metallicFactor": float(np.clip(mat.metallic_factor, 0, 1)),
            "roughnessFactor": float(np.clip(mat.roughness_factor, 0, 1)),
        }
        if mat.base_color is not None:
            pbr["baseColorTexture"] = self.texture_info(mat, mat.base_color, f"{stem}_basecolor")
        if mat.orm is not None:
            pbr["metallicRoughnessTexture"] = self.texture_info(mat, mat.orm, f"{stem}_orm")
        entry: dict[str, Any] = {"name": one_line(mat.name), "pbrMetallicRoughness": pbr, "doubleSided": True}
        if mat.normal is not None:
            entry["normalTexture"] = self.texture_info(mat, mat.normal, f"{stem}_normal")
        extras = {k: v for k, v in (("substance", one_line_strings(mat.substance)), ("scale", mat.scale),
                                    ("refinement", mat.refinement)) if v is not None}
        if mat.builtin:
            extras["builtin"] = True
        if extras:
            entry["extras"] = extras
        self.gltf["materials"].append(entry)
        self._materials[id(mat)] = len(self.gltf["materials"]) - 1
        return self._materials[id(mat)]

    def finish(self) -> dict[str, Any]:
        while len(self.blob) % 4:
            self.blob.append(0)
        for key in ("materials", "textures", "images", "samplers"):
            if not self.gltf[key]:
                del self.gltf[key]
        return self.gltf


def build_gltf(
    shape: Any,
    materials: Sequence[Any] | None = None,
    uv_transforms: Sequence[Any] | None = None,
    *,
    metadata: Mapping[str, Any] | None = None,
    resolve_ref: ResolveRef | None = None,
    embed_images: bool = True,
    texture_dir: str | None = None,
    max_texture_size: int | None = None,
    name: str = "photoshape",
    content_names: bool = False,
) -> tuple[dict[str, Any], bytes, dict[str, bytes]]:
    """The glTF JSON, its binary buffer and the external image files (empty when embedded).

    `content_names`: external images are named by their bytes (`pbr.content_file_name`), for a
    texture folder shared with other formats."""
    parts = export_parts(shape, materials, uv_transforms, bake_refinement=False)
    refined_uvs = {p.index: p.texcoords for p in export_parts(shape, materials, uv_transforms)}
    pbr = pbr_materials(shape, list(materials) if materials is not None else None,
                        resolve_ref=resolve_ref, max_texture_size=max_texture_size)
    by_index = {p.index: m for p, m in zip(shape.parts, pbr, strict=True)}
    b = _Builder(embed_images=embed_images, texture_dir=texture_dir, content_names=content_names)
    children: list[int] = []
    for part in parts:
        material = by_index[part.index]
        attributes = {
            "POSITION": b.accessor(part.positions, "VEC3", ARRAY_BUFFER, bounds=True),
            "NORMAL": b.accessor(part.normals, "VEC3", ARRAY_BUFFER),
            "TEXCOORD_0": b.accessor(gltf_texcoords(part.texcoords), "VEC2", ARRAY_BUFFER),
        }
        if material.normal is not None:
            # from the UVs the textures are sampled at (refinement included), as Mitsuba's frame is
            frame = tangents(part.positions, part.normals, refined_uvs[part.index], part.faces)
            attributes["TANGENT"] = b.accessor(frame, "VEC4", ARRAY_BUFFER)
        primitive = {
            "attributes": attributes,
            "indices": b.accessor(part.faces.reshape(-1), "SCALAR", ELEMENT_ARRAY_BUFFER),
            "material": b.material(material),
            "mode": 4,
        }
        b.gltf["meshes"].append({"name": one_line(part.name), "primitives": [primitive]})
        b.gltf["nodes"].append({"name": one_line(part.name), "mesh": len(b.gltf["meshes"]) - 1,
                                "extras": {"part_index": part.index}})
        children.append(len(b.gltf["nodes"]) - 1)
    b.gltf["nodes"].append({"name": one_line(name), "children": children})
    b.gltf["scenes"].append({"name": one_line(name), "nodes": [len(b.gltf["nodes"]) - 1]})
    if metadata:  # viewers show these strings as they are: one line each, like every export
        b.gltf["asset"]["extras"] = one_line_strings(json.loads(json.dumps(metadata, default=str)))
        copyright_ = metadata.get("copyright")
        if copyright_:
            b.gltf["asset"]["copyright"] = one_line(copyright_)
    gltf = b.finish()
    gltf["buffers"].append({"byteLength": len(b.blob)})
    return gltf, bytes(b.blob), b.image_files


def write_glb(path: str | Path, shape: Any, materials: Sequence[Any] | None = None,
              uv_transforms: Sequence[Any] | None = None, **kwargs: Any) -> Path:
    """Write a self-contained binary glTF (.glb): textures embedded in the BIN chunk."""
    gltf, blob, _ = build_gltf(shape, materials, uv_transforms, embed_images=True, **kwargs)
    payload = json.dumps(gltf, separators=(",", ":"), sort_keys=True).encode()
    payload += b" " * (-len(payload) % 4)
    total = 12 + 8 + len(payload) + 8 + len(blob)
    data = b"".join([
        struct.pack("<III", GLB_MAGIC, 2, total),
        struct.pack("<II", len(payload), JSON_CHUNK), payload,
        struct.pack("<II", len(blob), BIN_CHUNK), blob,
    ])
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(data)
    return out


def write_gltf(path: str | Path, shape: Any, materials: Sequence[Any] | None = None,
               uv_transforms: Sequence[Any] | None = None, *, texture_dir: str = "textures",
               **kwargs: Any) -> list[Path]:
    """Write .gltf JSON + `<stem>.bin` + PNG/JPEG textures under `texture_dir`; returns all files."""
    out = Path(path)
    if out.suffix.lower() == ".glb":
        return [write_glb(out, shape, materials, uv_transforms, **kwargs)]
    gltf, blob, images = build_gltf(shape, materials, uv_transforms, embed_images=False,
                                    texture_dir=texture_dir, **kwargs)
    bin_name = f"{out.stem}.bin"
    gltf["buffers"][0]["uri"] = bin_name
    out.parent.mkdir(parents=True, exist_ok=True)
    written = [out, out.parent / bin_name]
    (out.parent / bin_name).write_bytes(blob)
    for rel, data in images.items():
        target = out.parent / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
        written.append(target)
    out.write_text(json.dumps(gltf, indent=1, sort_keys=True))
    return written
