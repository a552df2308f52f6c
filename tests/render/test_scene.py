"""build_scene: the scene dict is data that says what will be rendered."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.specs import MaterialSpec, UVTransform
from photoshape_flow.render.testing import box_part, quad_part

from .conftest import write_png

pytestmark = pytest.mark.render


def shape() -> ShapeMesh:
    return ShapeMesh(parts=[box_part(1, (0, 0, 0), (0.2, 0.3, 0.2)), box_part(2, (0, -0.4, 0), (0.3, 0.05, 0.3))])


def test_beauty_scene_structure(renderer, constant_envmap) -> None:  # type: ignore[no-untyped-def]
    from photoshape_flow.render.scene import SceneOptions, build_scene, part_key

    env = constant_envmap(1.0)
    env = type(env)(env.path, scale=1.5, rotation=math.pi / 2)
    camera = Camera(0.4, 0.2, 1.8, 55.0)
    scene = build_scene(shape(), [MaterialSpec("a"), MaterialSpec("b")], env, camera, SceneOptions(size=24, spp=3))
    assert scene["integrator"] == {"type": "path", "max_depth": 8, "hide_emitters": True}
    sensor = scene["sensor"]
    assert sensor["fov_axis"] == "x" and sensor["fov"] == 55.0
    assert np.allclose(np.array(sensor["to_world"].matrix), camera.to_world(), atol=1e-6)
    assert sensor["film"]["width"] == sensor["film"]["height"] == 24 and sensor["film"]["pixel_format"] == "rgba"
    assert scene["emitter"]["type"] == "envmap" and scene["emitter"]["scale"] == 1.5
    rotated = np.array(scene["emitter"]["to_world"].matrix)[:3, :3]
    assert np.allclose(rotated @ [0, 0, 1], [1, 0, 0], atol=1e-6)  # +pi/2 about +y takes +z to +x
    assert {part_key(1), part_key(2)} <= set(scene) and "floor" not in scene
    floored = build_scene(shape(), [None, None], None, camera, SceneOptions(mode="aov", floor=True))
    assert floored["integrator"]["type"] == "aov" and "emitter" not in floored and "floor" not in floored
    lit = build_scene(shape(), [MaterialSpec("a"), MaterialSpec("b")], None, camera, SceneOptions(floor=True))
    assert lit["emitter"]["type"] == "constant" and lit["floor"]["type"] == "rectangle"


def test_scene_errors(renderer) -> None:  # type: ignore[no-untyped-def]
    from photoshape_flow.render.scene import SceneOptions, build_scene

    camera = Camera(0.0, 0.0)
    with pytest.raises(ValueError, match="one material per part"):
        build_scene(shape(), [MaterialSpec("a")], None, camera, SceneOptions())
    with pytest.raises(ValueError, match="one UV transform per part"):
        build_scene(shape(), [MaterialSpec("a")] * 2, None, camera, SceneOptions(uv_transforms=(None,)))
    with pytest.raises(ValueError, match="resolve built-ins"):
        build_scene(shape(), [MaterialSpec("a"), None], None, camera, SceneOptions())
    with pytest.raises(ValueError, match="texture file missing"):
        build_scene(shape(), [MaterialSpec("a", maps={"albedo": Path("/nope.png")}), MaterialSpec("b")], None,
                    camera, SceneOptions())


def test_material_bsdf_mapping(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from photoshape_flow.render.scene import material_bsdf

    spec_map = write_png(tmp_path / "spec.png", np.full((4, 4), 51, np.uint8))
    albedo = write_png(tmp_path / "albedo.png", np.full((4, 4, 3), 128, np.uint8))
    normal = write_png(tmp_path / "normal.png", np.full((4, 4, 3), [128, 128, 255], np.uint8))
    bsdf = material_bsdf(MaterialSpec("m", maps={"albedo": albedo, "normal": normal, "specular": spec_map},
                                      params={"roughness": 0.4}))
    assert bsdf["type"] == "normalmap" and bsdf["normalmap"]["raw"] is True
    principled = bsdf["bsdf"]
    assert principled["type"] == "principled"
    assert all(principled[slot]["raw"] is True for slot in ("base_color", "roughness", "metallic"))
    assert np.allclose(np.array(principled["base_color"]["bitmap"]), 0.21586, atol=1e-4)  # sRGB 128 decoded once
    assert np.allclose(np.array(bsdf["normalmap"]["bitmap"]), [128 / 255, 128 / 255, 1.0], atol=1e-6)  # data
    assert principled["specular"] == pytest.approx(0.2, abs=1e-3)  # mean of the map, as data
    assert np.allclose(np.array(principled["roughness"]["bitmap"]), 0.4)
    analytic = material_bsdf(MaterialSpec("a", params={"albedo": [0.5, 0.5, 0.5]}))["bsdf"]
    assert np.allclose(np.array(analytic["base_color"]["bitmap"]), 0.21404, atol=1e-4)  # sRGB -> linear
    assert analytic["specular"] == 0.5


def test_mitsuba_uvs_apply_formula_then_flip_v(renderer) -> None:  # type: ignore[no-untyped-def]
    from photoshape_flow.render.scene import mitsuba_uvs

    quad = quad_part(1, [[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0]], uv_size=(4.0, 4.0))  # D = 4
    uvs = mitsuba_uvs(quad, MaterialSpec("m", scale=0.5), None)  # x 1/2 / 0.5 = x1
    assert np.allclose(uvs, [[0, 1], [4, 1], [4, -3], [0, -3]])
    shifted = mitsuba_uvs(quad, MaterialSpec("m", scale=None), UVTransform(offset=(0.25, 0.5)))
    assert np.allclose(shifted[0], [0.25, 0.5]) and np.allclose(shifted[2], [4.25, -3.5])
