"""glTF 2.0 / GLB reader (through trimesh): one part per material, scene transforms applied.

Primitives are visited in scene-graph order; those sharing a material are merged into one part, so
parts are numbered in the order their material first appears, as for OBJ `usemtl` groups. trimesh
already flips glTF's V coordinate into the OBJ convention. The PBR base colour factor becomes the
built-in albedo (glTF factors are linear; the contract stores sRGB), the base colour texture is kept.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.geometry.raw import BadShapeError, RawMaterial, RawPart, RawShape, ShapeTooLargeError


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _material(material: Any, fallback_name: str) -> RawMaterial:
    name = str(getattr(material, "name", None) or fallback_name)
    albedo = (0.8, 0.8, 0.8)
    roughness = 1.0
    metallic = 0.0
    texture = None
    extra: dict[str, Any] = {"origin": "gltf"}
    base = getattr(material, "baseColorFactor", None)
    if base is not None:
        rgba = np.asarray(base, np.float64).ravel()
        if rgba.max() > 1.0:  # trimesh may hand back uint8 colours
            rgba = rgba / 255.0
        albedo = tuple(float(c) for c in _linear_to_srgb(rgba[:3]))
        if len(rgba) > 3 and rgba[3] < 1.0:
            extra["opacity"] = float(rgba[3])
    elif getattr(material, "baseColorTexture", None) is None and hasattr(material, "main_color"):
        rgb = np.asarray(material.main_color, np.float64).ravel()[:3] / 255.0
        albedo = tuple(float(c) for c in rgb)
    rough = getattr(material, "roughnessFactor", None)
    if rough is not None and np.isfinite(rough):
        roughness = float(np.clip(rough, 0.0, 1.0))
    metal = getattr(material, "metallicFactor", None)
    if metal is not None and np.isfinite(metal):
        metallic = float(np.clip(metal, 0.0, 1.0))
    elif metal is None and hasattr(material, "metallicFactor"):
        metallic = 1.0  # glTF default when the factor is absent
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)
    if image is not None:
        texture = image
    if getattr(material, "metallicRoughnessTexture", None) is not None:
        extra["has_metallic_roughness_texture"] = True
    return RawMaterial(name=name, albedo=albedo, roughness=roughness, metallic=metallic,
                       texture_image=texture, extra=extra)


def _node_order(path: Path) -> dict[str, int]:
    """glTF node name -> index in the file's `nodes` array."""
    import json
    import struct

    try:
        data = path.read_bytes()
        if data[:4] == b"glTF":
            length, kind = struct.unpack("<I4s", data[12:20])
            doc = json.loads(data[20 : 20 + length]) if kind == b"JSON" else {}
        else:
            doc = json.loads(data)
        nodes = doc.get("nodes", []) if isinstance(doc, dict) else []
        return {str(n.get("name")): i for i, n in enumerate(nodes) if isinstance(n, dict) and n.get("name")}
    except (OSError, ValueError, struct.error):
        return {}


def parse_gltf(path: Path, *, max_faces: int | None = None) -> RawShape:
    """Read a .gltf (with its buffers and images beside it) or .glb into material parts."""
    import trimesh

    path = Path(path)
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # trimesh raises many types on corrupt input
        raise BadShapeError(f"{path.name}: unreadable glTF ({type(exc).__name__}: {exc})") from exc
    total = 0
    order: list[str] = []
    pieces: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]] = {}
    materials: dict[str, RawMaterial] = {}
    nodes: list[str] = []
    warnings: list[str] = []
    # file order: meshes/primitives as loaded (trimesh keeps load order), then nodes instancing them
    order_in_file = _node_order(path)
    geometry_rank = {name: i for i, name in enumerate(scene.geometry)}
    nodes_in_order = sorted(
        scene.graph.nodes_geometry,
        key=lambda n: (geometry_rank.get(scene.graph[n][1], 1 << 30), order_in_file.get(str(n), 1 << 30), str(n)),
    )
    for node in nodes_in_order:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry.get(geom_name)
        if geom is None or not hasattr(geom, "faces") or len(geom.faces) == 0:
            continue
        faces = np.asarray(geom.faces, np.int64).reshape(-1, 3)
        total += len(faces)
        if max_faces is not None and total > max_faces:
            raise ShapeTooLargeError(f"{path.name}: more than {max_faces} faces (limit)")
        vertices = np.asarray(geom.vertices, np.float64).reshape(-1, 3)
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise BadShapeError(f"{path.name}: primitive {geom_name!r} has face indices out of range")
        homogeneous = np.concatenate([vertices, np.ones((len(vertices), 1))], axis=1)
        vertices = (homogeneous @ np.asarray(transform, np.float64).T)[:, :3]
        visual = getattr(geom, "visual", None)
        material = getattr(visual, "material", None)
        uv = getattr(visual, "uv", None)
        uvs = None
        if uv is not None and len(uv) == len(vertices):
            uvs = np.asarray(uv, np.float64).reshape(-1, 2)
        key = "default"
        if material is not None:
            key = str(getattr(material, "name", None) or f"material_{len(order) + 1}")
        if key not in pieces:
            order.append(key)
            pieces[key] = []
            materials[key] = _material(material, key) if material is not None else RawMaterial(name="default")
        pieces[key].append((vertices, faces, uvs))
        nodes.append(str(node))
    if total == 0:
        raise BadShapeError(f"{path.name}: no faces")
    parts: list[RawPart] = []
    for key in order:
        group = pieces[key]
        with_uv = all(u is not None for _, _, u in group)
        if not with_uv and any(u is not None for _, _, u in group):
            warnings.append(f"{path.name}: material {key!r} has UVs on some primitives only; they are regenerated")
        verts, faces, uvs_all = [], [], []
        offset = 0
        for v, f, u in group:
            verts.append(v)
            faces.append(f + offset)
            if with_uv:
                uvs_all.append(u)
            offset += len(v)
        vertices = np.concatenate(verts)
        if not np.isfinite(vertices[np.unique(np.concatenate(faces))]).all():
            raise BadShapeError(f"{path.name}: non-finite vertex coordinates")
        part_uvs = np.concatenate(uvs_all) if with_uv else None
        if part_uvs is not None and not np.isfinite(part_uvs).all():
            warnings.append(f"{path.name}: material {key!r} has non-finite UVs; they are regenerated")
            part_uvs = None
        parts.append(RawPart(name=key, vertices=vertices, faces=np.concatenate(faces), uvs=part_uvs,
                             material=materials[key], meta={"primitives": len(group)}))
    meta = {"source_format": "glb" if path.suffix.lower() == ".glb" else "gltf", "materials": order, "nodes": nodes}
    return RawShape(parts=parts, meta=meta, warnings=warnings)
