"""Mitsuba XML export: the written scene reloads and renders what the renderer's scene dict renders."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.export.mitsuba_xml import concrete_materials, write_mitsuba_xml
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.specs import EnvmapSpec, UVTransform

pytestmark = pytest.mark.render


def test_xml_reload_renders_the_same_image(tmp_path, tiny_shape, tiny_materials):
    """The XML, reloaded and rendered with Mitsuba's defaults, gives the Renderer's image at the same seed."""
    from photoshape_flow.render.renderer import Renderer
    from photoshape_flow.render.runtime import ensure_mitsuba

    mi = ensure_mitsuba()
    env = np.ones((8, 16, 3), np.float32)
    env[:4] *= 3.0  # brighter sky than ground, so lighting direction matters
    mi.Bitmap(env).write(str(tmp_path / "env.exr"))
    envmap = EnvmapSpec(tmp_path / "env.exr", scale=1.2, rotation=0.4)
    camera = Camera(0.6, 0.3, 2.0, 50.0)
    jitters = [UVTransform(1.3, 0.5, (0.1, 0.2)), None]
    materials = [tiny_materials[0], None]  # an SVBRDF part and a built-in part

    xml = write_mitsuba_xml(tmp_path / "x" / "scene.xml", tiny_shape, materials, envmap, camera,
                            uv_transforms=jitters, size=24, spp=8, floor=True, seed=3)
    folder = xml.parent
    assert sorted(p.name for p in (folder / "meshes").iterdir()) == ["part_0001.ply", "part_0002.ply"]
    assert "$spp" in xml.read_text() and str(tmp_path) not in xml.read_text()  # relocatable

    rendered = Renderer(resolve=lambda ref: tmp_path / ref).beauty(
        tiny_shape, concrete_materials(tiny_shape, materials, None), camera, envmap, size=24, spp=8,
        uv_transforms=jitters, background="transparent", floor=True, seed=3)
    reloaded = np.asarray(mi.render(mi.load_file(str(xml))))  # seed 0: the XML's sampler holds seed 3
    assert reloaded.shape == (24, 24, 4)
    assert rendered.alpha.mean() > 0.2  # the shape is in view
    np.testing.assert_allclose(reloaded[..., 3], rendered.alpha, atol=1e-3)
    np.testing.assert_allclose(reloaded[..., :3], rendered.hdr, atol=2e-3, rtol=1e-3)
    # another seed gives other noise: the comparison above can fail
    assert np.abs(np.asarray(mi.render(mi.load_file(str(xml)), seed=4))[..., :3] - rendered.hdr).max() > 1e-2


def test_xml_reload_renders_the_refined_look(tmp_path, tiny_shape, tiny_materials):
    """A refined material (tint, roughness, UV scale and rotation) reloads as the Renderer rendered it,
    and that look differs from the unrefined material's."""
    from dataclasses import replace

    from photoshape_flow.render.renderer import Renderer
    from photoshape_flow.render.runtime import ensure_mitsuba
    from photoshape_flow.render.specs import Refinement

    mi = ensure_mitsuba()
    camera = Camera(0.6, 0.3, 2.0, 50.0)
    refined = [replace(tiny_materials[0], refinement=Refinement((1.6, 0.7, 0.5), 1.5, 2.0, 0.8)), tiny_materials[1]]
    xml = write_mitsuba_xml(tmp_path / "r" / "scene.xml", tiny_shape, refined, None, camera, size=24, spp=8, seed=2)
    renderer = Renderer()
    rendered = renderer.beauty(tiny_shape, refined, camera, None, size=24, spp=8, background="transparent", seed=2)
    plain = renderer.beauty(tiny_shape, tiny_materials, camera, None, size=24, spp=8, background="transparent",
                            seed=2)
    reloaded = np.asarray(mi.render(mi.load_file(str(xml))))
    np.testing.assert_allclose(reloaded[..., :3], rendered.hdr, atol=2e-3, rtol=1e-3)
    assert np.abs(rendered.hdr - plain.hdr).max() > 0.05
