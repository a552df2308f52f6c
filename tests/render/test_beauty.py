"""Beauty renders: material mapping against analytic expectations under a uniform envmap."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec, UVTransform, material_from_builtin, srgb_to_linear
from photoshape_flow.render.testing import box_part, quad_part

from .conftest import write_exr, write_png

pytestmark = pytest.mark.render

# a 1x1 plane seen head-on, filling the image exactly (fov = 2 atan(0.5 / 2))
FILL = Camera(0.0, 0.0, 2.0, math.degrees(2 * math.atan(0.25)))
# No specular lobe; principled's (Disney) diffuse has a roughness-dependent retro-reflection: at
# roughness 0.3 its reflectance at normal view equals the albedo (measured: within 0.1% at 256 spp;
# +3.5% at roughness 1), so a plane behaves as a Lambertian a under uniform light.
DIFFUSE = {"roughness": 0.3, "metallic": 0.0, "specular": 0.0}


def plane(size: float = 0.5) -> ShapeMesh:
    s = size
    return ShapeMesh(parts=[quad_part(1, [[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]])])


def centre(image: np.ndarray, border: int = 4) -> np.ndarray:
    return image[border:-border, border:-border].reshape(-1, image.shape[-1]).mean(axis=0)


@pytest.mark.parametrize("radiance", [1.0, 0.5])
def test_analytic_diffuse_under_constant_envmap(renderer, constant_envmap, radiance: float) -> None:  # type: ignore[no-untyped-def]
    albedo = [0.8, 0.5, 0.2]
    material = MaterialSpec("flat", params={"albedo": albedo, **DIFFUSE})
    env = constant_envmap(radiance)
    result = renderer.beauty(plane(), [material], FILL, env, size=32, spp=16)
    expected = srgb_to_linear(albedo) * radiance  # a * L
    assert np.allclose(centre(result.hdr), expected, rtol=0.03, atol=0.003)
    assert result.srgb.dtype == np.uint8 and result.srgb.shape == (32, 32, 3)
    assert result.hdr.dtype == np.float32 and result.alpha.shape == (32, 32)
    if radiance == 1.0:  # unit radiance: the 8-bit image shows the sRGB albedo itself
        assert np.allclose(centre(result.srgb.astype(float)), np.array(albedo) * 255, atol=4)


def test_albedo_map_is_srgb(renderer, constant_envmap, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    colour = np.array([200, 120, 40], np.uint8)
    path = write_png(tmp_path / "albedo.png", np.tile(colour, (8, 8, 1)))
    material = MaterialSpec("tex", maps={"albedo": path}, params=DIFFUSE)
    result = renderer.beauty(plane(), [material], FILL, constant_envmap(1.0), size=32, spp=8)
    assert np.allclose(centre(result.hdr), srgb_to_linear(colour / 255.0), rtol=0.03, atol=0.003)


def test_scalar_maps_are_raw_data(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A constant roughness/metallic map renders like the same analytic value (no sRGB decoding)."""
    sky = np.zeros((16, 32, 3), np.float32)
    sky[:6] = 1.0
    env = EnvmapSpec(write_exr(tmp_path / "sky.exr", sky))
    rough = write_png(tmp_path / "rough.png", np.full((4, 4), 128, np.uint8))
    metal = write_png(tmp_path / "metal.png", np.full((4, 4), 255, np.uint8))
    tilted = Camera(0.0, -0.3, 2.0, 30.0)  # the plane mirrors the sky's lower edge towards the camera
    base = {"albedo": [0.9, 0.6, 0.3], "specular": 0.5}

    def render(material: MaterialSpec) -> np.ndarray:
        return renderer.beauty(plane(), [material], tilted, env, size=16, spp=16, seed=3).hdr

    mapped = render(MaterialSpec("maps", maps={"roughness": rough, "metallic": metal}, params=base))
    analytic = render(MaterialSpec("params", params={**base, "roughness": 128 / 255, "metallic": 1.0}))
    linearised = float(srgb_to_linear(128 / 255))
    decoded = render(MaterialSpec("srgb", params={**base, "roughness": linearised, "metallic": 1.0}))
    dielectric = render(MaterialSpec("plastic", params={**base, "roughness": 128 / 255, "metallic": 0.0}))
    assert np.abs(mapped - analytic).mean() < 1e-4  # same samples, same values: identical images
    assert np.abs(decoded - analytic).mean() > 0.01  # what sRGB-decoding the map would have given
    assert np.abs(dielectric - analytic).mean() > 0.01


def test_uv_scale_formula_sets_tile_count(renderer, constant_envmap, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    checker = np.kron([[0, 1], [1, 0]], np.ones((16, 16)))
    tex = write_png(tmp_path / "checker.png", (np.stack([checker] * 3, -1) * 255).astype(np.uint8))
    env = constant_envmap(1.0)
    size = 64

    def squares(scale: float, jitter: UVTransform | None = None) -> int:
        material = MaterialSpec("checker", maps={"albedo": tex}, params=DIFFUSE, scale=scale)
        jitters = [jitter] if jitter else None
        image = renderer.beauty(plane(), [material], FILL, env, size=size, spp=16, uv_transforms=jitters).hdr
        row = image[size // 4 + 2, :, 1]  # a row away from the v = 0.5 checker edge
        bright = row > 0.4  # squares are ~0 (albedo 0) or ~1 (albedo 1 under unit radiance)
        return int(np.count_nonzero(np.diff(bright.astype(int)))) + 1

    assert squares(0.5) == 4  # 1 world unit / 0.5 per tile = 2 tiles = 4 checker squares
    assert squares(0.25) == 8
    assert squares(0.5, UVTransform(scale=2.0)) == 8  # jitter scale on top of the formula


def test_builtin_texture_keeps_mesh_uvs_upright(renderer, constant_envmap, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    image = np.zeros((8, 8, 3), np.uint8)
    image[:4] = [255, 0, 0]  # top half red
    image[4:] = [0, 0, 255]  # bottom half blue
    write_png(tmp_path / "ab.png", image)
    quad = plane().parts[0]
    quad.builtin_material = {"albedo": [1, 1, 1], "roughness": 1.0, "texture": "ab.png"}
    shape = ShapeMesh(parts=[quad])
    from photoshape_flow.render.renderer import Renderer

    local = Renderer(resolve=lambda ref: tmp_path / ref)
    result = local.beauty(shape, None, FILL, constant_envmap(1.0), size=32, spp=4)
    top, bottom = result.hdr[4, 16], result.hdr[28, 16]
    assert top[0] > 0.5 > top[2] and bottom[2] > 0.5 > bottom[0]
    assert material_from_builtin(quad.builtin_material, lambda ref: tmp_path / ref).scale is None


def test_normal_map_opengl_convention_and_rotation(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sky = np.zeros((16, 32, 3), np.float32)
    sky[:8] = 1.0  # light from the upper hemisphere only (+y up)
    env = EnvmapSpec(write_exr(tmp_path / "sky.exr", sky))
    tilt_up = np.array([0.5, 0.5 + 0.5 * 0.6, 0.5 + 0.5 * 0.8])  # tangent normal (0, 0.6, 0.8): green = up
    normal = write_png(tmp_path / "normal.png", np.tile(np.round(tilt_up * 255).astype(np.uint8), (4, 4, 1)))
    flat = MaterialSpec("flat", params={"albedo": [0.8] * 3, **DIFFUSE})
    bumped = MaterialSpec("bumped", maps={"normal": normal}, params={"albedo": [0.8] * 3, **DIFFUSE})

    def brightness(material: MaterialSpec, jitter: UVTransform | None = None) -> float:
        jitters = [jitter] if jitter else None
        result = renderer.beauty(plane(), [material], FILL, env, size=16, spp=16, uv_transforms=jitters)
        return float(centre(result.hdr)[1])

    base = brightness(flat)
    assert brightness(bumped) > base * 1.15  # normals tilted towards the lit sky
    assert brightness(bumped, UVTransform(rotation=math.pi)) < base * 0.85  # texture upside down: tilted away


def test_backgrounds_floor_and_saturation(renderer, constant_envmap) -> None:  # type: ignore[no-untyped-def]
    shape = ShapeMesh(parts=[box_part(1, (0.0, 0.0, 0.0), (0.2, 0.2, 0.2))])
    camera = Camera(0.3, 0.3, 2.0, 50.0)
    white = MaterialSpec("white", params={"albedo": [0.7, 0.7, 0.7], **DIFFUSE})
    env = constant_envmap(1.0)
    out = renderer.beauty(shape, [white], camera, env, size=32, spp=4, background="white")
    assert out.alpha[0, 0] == 0 and out.alpha[16, 16] == pytest.approx(1.0)
    assert np.all(out.srgb[0, 0] == 255) and np.allclose(out.hdr[0, 0], 1.0)
    clear = renderer.beauty(shape, [white], camera, env, size=32, spp=4, background="transparent")
    assert np.all(clear.srgb[0, 0] == 0) and np.all(clear.hdr[0, 0] == 0)
    floored = renderer.beauty(shape, [white], camera, env, size=32, spp=4, floor=True)
    assert floored.alpha[-1].mean() == pytest.approx(1.0) and out.alpha[-1].mean() == 0.0
    assert out.saturated_fraction < 0.05
    bright = renderer.beauty(shape, [white], camera, constant_envmap(6.0, "bright.exr"), size=32, spp=4)
    assert bright.saturated_fraction > 0.9
    with pytest.raises(ValueError, match="background"):
        renderer.beauty(shape, [white], camera, env, size=16, spp=1, background="grey")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="one material per part"):
        renderer.beauty(shape, [white, white], camera, env, size=16, spp=1)


def test_beauty_kernel_shared_by_material_kinds(renderer, constant_envmap, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Textured and analytic materials share one BSDF graph, so changing them compiles nothing new."""
    import drjit as dr

    tex = write_png(tmp_path / "t.png", np.full((4, 4, 3), 90, np.uint8))

    def shape() -> ShapeMesh:  # a new object each time: a fresh scene, not the cached one
        return ShapeMesh(parts=[box_part(1, (-0.2, 0, 0), (0.1, 0.1, 0.1)), box_part(2, (0.2, 0, 0), (0.1, 0.1, 0.1))])

    camera, env = Camera(0.2, 0.2, 2.0, 50.0), constant_envmap(1.0)
    analytic = [MaterialSpec("a", params={"albedo": [0.1, 0.2, 0.3], "roughness": 0.2}), MaterialSpec("b")]
    mixed = [MaterialSpec("c", maps={"albedo": tex}), MaterialSpec("d", params={"metallic": 1.0})]

    def kernels(target: ShapeMesh, materials: list[MaterialSpec]) -> set[str]:
        dr.kernel_history_clear()
        renderer.beauty(target, materials, camera, env, size=20, spp=2)
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT and k["size"] >= 20 * 20}

    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        # Kernels also depend on the layout of Dr.Jit's instance registry, which the first build after
        # other tests' scenes changes; hence a warm-up build before comparing.
        kernels(shape(), mixed)
        fresh_analytic = kernels(shape(), analytic)
        fresh_mixed = kernels(shape(), mixed)
        cached_shape = shape()
        kernels(cached_shape, mixed)
        updated_analytic = kernels(cached_shape, analytic)  # the cached scene, parameters rewritten
        updated_mixed = kernels(cached_shape, mixed)
    assert fresh_analytic and fresh_mixed <= fresh_analytic
    assert updated_analytic and updated_mixed <= updated_analytic


def test_cached_scene_update_equals_fresh_build(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A render right after another (other materials, camera, envmap scale and rotation, UV jitter)
    equals the same render by another Renderer: nothing of the previous render carries over.
    (tests/render/test_pool.py compares the persistent scene with a freshly loaded one.)"""
    from photoshape_flow.render.renderer import Renderer

    sky = np.zeros((8, 16, 3), np.float32)
    sky[:3] = [2.0, 1.5, 1.0]
    env_path = write_exr(tmp_path / "sky.exr", sky)
    tex = write_png(tmp_path / "t.png", np.random.default_rng(0).integers(0, 255, (8, 8, 3), dtype=np.uint8))
    shape = ShapeMesh(parts=[box_part(1, (0, 0, 0), (0.2, 0.2, 0.2)), box_part(2, (0, -0.3, 0), (0.35, 0.05, 0.35))])
    first = [MaterialSpec("a", params={"albedo": [0.9, 0.2, 0.2]}), MaterialSpec("b", params={"metallic": 1.0})]
    second = [MaterialSpec("c", maps={"albedo": tex}, params={"roughness": 0.2}, scale=0.1), MaterialSpec("d")]
    kwargs = {"size": 24, "spp": 4, "seed": 5, "uv_transforms": [UVTransform(1.5, 0.7, (0.1, 0.2)), None]}
    renderer.beauty(shape, first, Camera(0.1, 0.2), EnvmapSpec(env_path, 1.0, 0.0), size=24, spp=4)
    updated = renderer.beauty(shape, second, Camera(1.0, 0.4, 1.8, 55.0), EnvmapSpec(env_path, 1.3, 2.0), **kwargs)
    fresh = Renderer().beauty(shape, second, Camera(1.0, 0.4, 1.8, 55.0), EnvmapSpec(env_path, 1.3, 2.0), **kwargs)
    assert np.allclose(updated.hdr, fresh.hdr, atol=1e-4)
    assert np.allclose(updated.alpha, fresh.alpha, atol=1e-5)  # other kernel, other rounding
