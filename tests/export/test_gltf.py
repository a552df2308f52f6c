"""glTF/GLB export: valid per the Khronos validator, textures and metadata where a viewer expects them."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.export.gltf import build_gltf, write_glb, write_gltf
from photoshape_flow.render.specs import UVTransform, uv_matrix


def _validate(path: Path) -> dict:
    from photoshape_flow.export.node_tools import ProgramMissing
    from photoshape_flow.export.validate import validate_gltf

    try:
        return validate_gltf(path)
    except ProgramMissing as exc:
        pytest.skip(str(exc))


def _read_glb(path: Path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<III", data, 0)
    assert (magic, version, total) == (0x46546C67, 2, len(data))
    json_len, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20 : 20 + json_len])
    bin_len, _ = struct.unpack_from("<II", data, 20 + json_len)
    return doc, data[28 + json_len : 28 + json_len + bin_len]


def test_glb_passes_khronos_validator(tmp_path, tiny_shape, tiny_materials):
    meta = {"copyright": "oak_01: CC0-1.0", "pair_id": 7}
    path = write_glb(tmp_path / "a.glb", tiny_shape, tiny_materials,
                     [UVTransform(scale=1.5, rotation=0.3, offset=(0.1, 0.2)), None], metadata=meta)
    report = _validate(path)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"]
    info = report["info"]
    assert info["drawCallCount"] == 2 and info["materialCount"] == 2
    assert info["totalTriangleCount"] == tiny_shape.num_faces
    doc, _ = _read_glb(path)
    assert doc["asset"]["copyright"] == "oak_01: CC0-1.0" and doc["asset"]["extras"]["pair_id"] == 7
    oak = doc["materials"][0]
    assert oak["name"] == "oak_01" and "normalTexture" in oak
    assert {"baseColorTexture", "metallicRoughnessTexture"} <= set(oak["pbrMetallicRoughness"])


def test_gltf_with_external_files_passes_validator(tmp_path, tiny_shape, tiny_materials):
    files = write_gltf(tmp_path / "out" / "a.gltf", tiny_shape, tiny_materials)
    assert (tmp_path / "out" / "a.bin").is_file()
    assert any(f.parent.name == "textures" and f.suffix == ".png" for f in files)
    report = _validate(files[0])
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
    assert report["info"]["resources"]  # the validator loaded the .bin and the images


def test_builtin_parts_and_broken_input_are_reported(tmp_path, tiny_shape):
    path = write_glb(tmp_path / "b.glb", tiny_shape, [None, None])
    report = _validate(path)
    assert report["issues"]["numErrors"] == 0
    doc, _ = _read_glb(path)
    chrome = doc["materials"][1]["pbrMetallicRoughness"]
    assert chrome["metallicFactor"] == 1.0 and chrome["roughnessFactor"] == pytest.approx(0.3)
    # a corrupted file is caught by the validator (the check can fail)
    data = bytearray(path.read_bytes())
    data[12 + 8 + 2] = ord("#")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(bytes(data))
    assert _validate(bad)["issues"]["numErrors"] > 0


def test_texcoords_bake_the_texture_scale_formula(tiny_shape, tiny_materials):
    jitter = UVTransform(scale=2.0, rotation=0.5, offset=(0.25, 0.0))
    doc, blob, _ = build_gltf(tiny_shape, tiny_materials, [jitter, None])
    part = tiny_shape.parts[0]
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    view = doc["bufferViews"][acc["bufferView"]]
    uv = np.frombuffer(blob, "<f4", acc["count"] * 2, view["byteOffset"]).reshape(-1, 2)
    m = uv_matrix(part.uv_density, 0.25, jitter)
    expected = part.uvs @ m[:2, :2].T + m[:2, 2]
    expected[:, 1] = 1.0 - expected[:, 1]  # glTF: v = 0 at the image's top row
    np.testing.assert_allclose(uv, expected, rtol=1e-5, atol=1e-5)
    assert not np.allclose(uv, part.uvs)
    # the same numbers the renderer hands Mitsuba
    from photoshape_flow.render.scene import mitsuba_uvs

    np.testing.assert_allclose(uv, mitsuba_uvs(part, tiny_materials[0], jitter), rtol=1e-5, atol=1e-5)


def _khr_apply(transform: dict, uv: np.ndarray) -> np.ndarray:
    """KHR_texture_transform as its GLSL reference computes it: T(offset) R(rotation) S(scale) uv."""
    c, s = np.cos(transform["rotation"]), np.sin(transform["rotation"])
    rotation = np.array([[c, -s], [s, c]])  # mat3(cos, sin, 0, -sin, cos, 0, ...) is column-major
    return (uv * np.array(transform["scale"])) @ rotation.T + np.array(transform["offset"])


def test_refined_material_carries_tint_roughness_and_khr_texture_transform(tmp_path, tiny_shape, tiny_materials):
    from dataclasses import replace

    from photoshape_flow.render.scene import mitsuba_uvs
    from photoshape_flow.render.specs import Refinement

    refinement = Refinement(tint=(0.9, 0.6, 0.5), roughness_scale=0.7, uv_scale=1.4, uv_rotation=np.pi / 4)
    refined = [replace(tiny_materials[0], refinement=refinement), tiny_materials[1]]
    path = write_glb(tmp_path / "r.glb", tiny_shape, refined, [UVTransform(scale=1.2, rotation=0.3), None])
    report = _validate(path)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"]
    doc, blob = _read_glb(path)
    assert doc["extensionsUsed"] == ["KHR_texture_transform"] and "extensionsRequired" not in doc
    oak, steel = doc["materials"]
    pbr = oak["pbrMetallicRoughness"]
    assert pbr["baseColorFactor"] == pytest.approx([0.9, 0.6, 0.5, 1.0])
    assert pbr["roughnessFactor"] == pytest.approx(0.7)
    assert oak["extras"]["refinement"]["uv_scale"] == 1.4
    transform = pbr["baseColorTexture"]["extensions"]["KHR_texture_transform"]
    assert oak["normalTexture"]["extensions"]["KHR_texture_transform"] == transform
    assert "extensions" not in steel["pbrMetallicRoughness"]["baseColorTexture"]
    # the extension applied to the exported texcoords gives the UVs the renderer samples at
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    uv = np.frombuffer(blob, "<f4", acc["count"] * 2, doc["bufferViews"][acc["bufferView"]]["byteOffset"])
    np.testing.assert_allclose(_khr_apply(transform, uv.reshape(-1, 2)),
                               mitsuba_uvs(tiny_shape.parts[0], refined[0], UVTransform(scale=1.2, rotation=0.3)),
                               rtol=1e-4, atol=1e-4)


def test_a_tint_above_one_is_baked_into_the_texture(tiny_shape, tiny_materials):
    from dataclasses import replace

    from photoshape_flow.render.specs import Refinement

    plain, _, _ = build_gltf(tiny_shape, tiny_materials)
    refined = [replace(tiny_materials[0], refinement=Refinement(tint=(1.5, 1.0, 1.0))), tiny_materials[1]]
    doc, _, _ = build_gltf(tiny_shape, refined)
    assert doc["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]  # glTF max
    assert "extensionsUsed" not in doc  # no UV change: no extension
    assert len(doc["images"]) == len(plain["images"])  # another base colour image replaces the library's
    assert doc["images"][0] != plain["images"][0] or doc["bufferViews"] != plain["bufferViews"]
