"""Mitsuba XML export: the written scene reloads and renders what the renderer's scene dict renders."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.export.mitsuba_xml import concrete_materials, write_mitsuba_xml
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.specs import EnvmapSpec, UVTransform

pytestmark = pytest.mark.render


def test_xml_reload_renders_the_same_image(tmp_path, tiny_shape, tiny_materials):
    from photoshape_flow.render.runtime import ensure_mitsuba
    from photoshape_flow.render.scene import SceneOptions, build_scene

    mi = ensure_mitsuba()
    env = np.ones((8, 16, 3), np.float32)
    env[:4] *= 3.0  # brighter sky than ground, so lighting direction matters
    mi.Bitmap(env).write(str(tmp_path / "env.exr"))
    envmap = EnvmapSpec(tmp_path / "env.exr", scale=1.2, rotation=0.4)
    camera = Camera(0.6, 0.3, 2.0, 50.0)
    jitters = [UVTransform(1.3, 0.5, (0.1, 0.2)), None]
    materials = [tiny_materials[0], None]  # an SVBRDF part and a built-in part

    xml = write_mitsuba_xml(tmp_path / "x" / "scene.xml", tiny_shape, materials, envmap, camera,
                            uv_transforms=jitters, size=24, spp=8, floor=True)
    folder = xml.parent
    assert sorted(p.name for p in (folder / "meshes").iterdir()) == ["part_0001.ply", "part_0002.ply"]
    assert (folder / "textures" / "env.exr").is_file()
    assert "$spp" in xml.read_text() and str(tmp_path) not in xml.read_text()  # relocatable

    options = SceneOptions(size=24, spp=8, floor=True, uv_transforms=tuple(jitters))
    scene = build_scene(tiny_shape, concrete_materials(tiny_shape, materials, None), envmap, camera, options)
    direct = np.asarray(mi.render(mi.load_dict(scene), seed=3))
    reloaded = np.asarray(mi.render(mi.load_file(str(xml)), seed=3))
    assert direct.shape == reloaded.shape == (24, 24, 4)
    assert direct[..., 3].mean() > 0.2  # the shape is in view
    np.testing.assert_allclose(reloaded, direct, atol=1e-3, rtol=1e-3)
    # a different seed gives different noise: the comparison above can fail
    assert np.abs(np.asarray(mi.render(mi.load_file(str(xml)), seed=4)) - direct).max() > 1e-2
