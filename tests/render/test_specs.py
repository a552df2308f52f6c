"""Texture-scale formula, colour transfer functions and material specs (no Mitsuba)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.render.specs import (
    EnvmapSpec,
    MaterialSpec,
    UVTransform,
    apply_uv_matrix,
    linear_to_srgb,
    material_from_builtin,
    srgb_to_linear,
    uv_matrix,
)


def test_texture_scale_formula() -> None:
    # D = 4 (UV area 4x world area), tile of 0.5 world units: k = 1/sqrt(4)/0.5 = 1
    assert np.allclose(uv_matrix(4.0, 0.5), np.eye(3))
    # D = 1, tile 0.25: UVs x4 (four tiles per world unit)
    m = uv_matrix(1.0, 0.25)
    assert np.allclose(apply_uv_matrix(np.array([[1.0, 0.5]]), m), [[4.0, 2.0]])
    # scale None keeps the mesh UVs whatever the density
    assert np.allclose(uv_matrix(9.0, None), np.eye(3))


def test_jitter_is_applied_after_the_formula() -> None:
    jitter = UVTransform(scale=2.0, rotation=math.pi / 2, offset=(0.5, 0.25))
    m = uv_matrix(1.0, 0.5, jitter)  # k = 2, then x2, rotate 90 deg, offset
    out = apply_uv_matrix(np.array([[1.0, 0.0], [0.0, 1.0]]), m)
    assert np.allclose(out, [[0.5, 4.25], [-3.5, 0.25]], atol=1e-6)


def test_srgb_round_trip() -> None:
    x = np.linspace(0, 1, 101)
    assert np.allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-9)
    assert np.isclose(srgb_to_linear(0.5), 0.21404, atol=1e-4)


def test_material_spec_validation() -> None:
    with pytest.raises(ValueError, match="unknown map channel"):
        MaterialSpec("m", maps={"diffuse": Path("x.png")})
    with pytest.raises(ValueError, match="scale"):
        MaterialSpec("m", scale=0.0)
    spec = MaterialSpec("m", maps={"albedo": "a.png"})  # type: ignore[dict-item]
    assert isinstance(spec.maps["albedo"], Path)
    assert isinstance(EnvmapSpec("env.exr").path, Path)


def test_material_from_builtin(tmp_path: Path) -> None:
    seen = []

    def resolve(ref: str) -> Path:
        seen.append(ref)
        return tmp_path / ref

    spec = material_from_builtin(
        {"albedo": [0.2, 0.4, 0.6], "roughness": 0.3, "metallic": 1.0, "texture": "ab.png", "name": "wood"}, resolve
    )
    assert spec.name == "wood" and spec.scale is None
    assert spec.params == {"albedo": [0.2, 0.4, 0.6], "roughness": 0.3, "metallic": 1.0}
    assert spec.maps == {"albedo": tmp_path / "ab.png"} and seen == ["ab.png"]
    plain = material_from_builtin({}, resolve)
    assert plain.maps == {} and plain.params["albedo"] == [0.8, 0.8, 0.8]
    with pytest.raises(ValueError, match="albedo"):
        material_from_builtin({"albedo": [1, 2]}, resolve)
