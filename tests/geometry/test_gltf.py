"""glTF/GLB reading: one part per material, PBR factors, corrupt files rejected; real Poly Haven models."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tests.geometry.makers import write_glb

from photoshape_flow.geometry.gltf import parse_gltf
from photoshape_flow.geometry.prepare import prepare_shape
from photoshape_flow.geometry.preprocess import PreprocessOptions, preprocess
from photoshape_flow.geometry.raw import BadShapeError, ShapeTooLargeError


def test_glb_parts_per_material(tmp_path: Path) -> None:
    raw = parse_gltf(write_glb(tmp_path / "two.glb"))
    assert [p.name for p in raw.parts] == ["red", "blue"]
    red, blue = raw.parts
    assert red.material.albedo == pytest.approx((1.0, 0.0, 0.0))
    assert red.material.roughness == pytest.approx(0.4)
    assert blue.material.metallic == pytest.approx(1.0)
    assert red.uvs is not None and blue.uvs is None
    mesh = preprocess(raw)
    assert [p.meta["uv_source"] for p in mesh.parts] == ["source", "xatlas"]
    assert raw.meta["source_format"] == "glb"


def test_face_limit(tmp_path: Path) -> None:
    with pytest.raises(ShapeTooLargeError):
        parse_gltf(write_glb(tmp_path / "two.glb"), max_faces=5)


@pytest.mark.parametrize(
    "content", [b"", b"glTF\x02\x00\x00\x00garbage", b'{"asset": {"version": "2.0"}, "meshes": [{']
)
def test_corrupt_gltf_is_rejected(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "bad.glb"
    path.write_bytes(content)
    with pytest.raises(BadShapeError):
        parse_gltf(path)


def test_truncated_glb_is_rejected(tmp_path: Path) -> None:
    data = write_glb(tmp_path / "good.glb").read_bytes()
    path = tmp_path / "cut.glb"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(BadShapeError):
        parse_gltf(path)


@pytest.mark.realdata
def test_real_polyhaven_models(shared_data: Path) -> None:
    sofa = shared_data / "models" / "polyhaven_sofa_03" / "sofa_03_1k.gltf"
    prepared = prepare_shape(str(sofa), "gltf", str(sofa.parent), PreprocessOptions())
    names = [p.name for p in prepared.mesh.parts]
    assert names == ["sofa_03", "sofa_03_fringe"]
    assert all(p.meta["uv_source"] == "source" for p in prepared.mesh.parts)
    assert len(prepared.textures) >= 1  # the base colour texture travels with the part
    assert all(p.builtin_material["texture"] in prepared.textures for p in prepared.mesh.parts)
    lo, hi = prepared.mesh.bounds()
    assert np.isclose((hi - lo).max(), 1.0, atol=1e-5)
