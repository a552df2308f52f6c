"""The persistent beauty scene: new shapes, materials and envmaps reuse the compiled kernels, and a
render of the pool equals one of a freshly loaded `build_scene`."""

from __future__ import annotations

import gc
import math
from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec, UVTransform
from photoshape_flow.render.testing import box_part

from .conftest import write_exr, write_png

pytestmark = pytest.mark.render


def boxes(count: int, seed: int) -> ShapeMesh:
    rng = np.random.default_rng(seed)
    return ShapeMesh(
        parts=[
            box_part(i + 1, tuple(rng.uniform(-0.3, 0.3, 3)), tuple(rng.uniform(0.05, 0.15, 3)))
            for i in range(count)
        ]
    )


def test_slot_count() -> None:
    from photoshape_flow.render.pool import slot_count

    assert [slot_count(n) for n in (0, 1, 4, 5, 8, 9, 13, 17, 25, 33, 65)] == [4, 4, 4, 8, 8, 12, 16, 24, 32, 48, 96]


def test_new_shapes_materials_and_envmaps_compile_no_kernel(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """After one render in a pool, other shapes (other part and vertex counts), materials (other
    texture sizes, specular, metallic), envmaps (other files, resolutions, scale, rotation), UV
    jitter, the floor and the exact passes in between launch only kernels compiled already."""
    import drjit as dr

    rng = np.random.default_rng(0)
    envmaps = [
        EnvmapSpec(write_exr(tmp_path / f"env{k}.exr", rng.uniform(0.2, 2.0, (h, 2 * h, 3)).astype(np.float32)),
                   scale=1.0 + k, rotation=0.7 * k)
        for k, h in enumerate((8, 32, 300, 64))
    ]
    textures = [write_png(tmp_path / f"t{k}.png", rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
                for k, (h, w) in enumerate(((4, 4), (32, 16), (128, 128)))]

    def materials(count: int, k: int) -> list[MaterialSpec]:
        out = []
        for i in range(count):
            if (i + k) % 2:
                maps = {"albedo": textures[(i + k) % 3], "normal": textures[(i + k + 1) % 3]}
                out.append(MaterialSpec(f"t{i}", maps=maps, scale=0.2 + 0.1 * k))
            else:
                params = {"albedo": list(rng.uniform(0, 1, 3)), "specular": float(rng.uniform()),
                          "roughness": float(rng.uniform()), "metallic": float(k % 2)}
                out.append(MaterialSpec(f"c{i}", params=params))
        return out

    def render(k: int, count: int) -> set[str]:
        """Hashes of the large kernels (path tracer, shaded sweep) launched for one training-like item."""
        shape, camera = boxes(count, seed=k), Camera(0.4 * k, 0.2, 2.0, 50.0)
        dr.kernel_history_clear()
        renderer.beauty(shape, materials(count, k), camera, envmaps[k % len(envmaps)], size=24, spp=2, seed=k,
                        uv_transforms=[UVTransform(1.0 + 0.1 * k, 0.3 * k)] * count, floor=k % 2 == 1)
        renderer.part_ids(shape, camera, 24)
        renderer.sweep(shape, [camera, Camera(1.0, 0.3, 2.0, 50.0)], 24, shaded=True)
        history = dr.kernel_history()
        return {h["hash"] for h in history if h["type"] == dr.KernelType.JIT and h["operation_count"] >= 150}

    gc.collect()  # free other tests' Mitsuba objects now: live instances are part of every kernel
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        warm = render(0, 8) | render(1, 7)  # the pool grows to >= 8 slots; floor on and off
        later = [render(k, count) for k, count in ((2, 5), (3, 6), (4, 8), (5, 7))]
    assert warm
    assert all(kernels and kernels <= warm for kernels in later), [sorted(k - warm) for k in later]


def test_pool_render_equals_fresh_scene(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The pool, rewritten after a shape with more parts, renders what a freshly loaded scene renders
    (same seed): unused slots are invisible, UVs, textures, envmap and camera are all updated."""
    import mitsuba as mi

    from photoshape_flow.render.pool import ENVMAP_RESOLUTION
    from photoshape_flow.render.scene import SceneOptions, build_scene
    from photoshape_flow.render.tonemap import composite

    height, width = ENVMAP_RESOLUTION  # at the pool's resolution: no resampling, the same lighting
    sky = np.zeros((height, width, 3), np.float32)
    sky[: height // 3] = [2.0, 1.5, 1.0]
    sky[10:20, 40:60] = 20.0
    env = EnvmapSpec(write_exr(tmp_path / "sky.exr", sky), 1.3, 2.0)
    tex = write_png(tmp_path / "t.png", np.random.default_rng(0).integers(0, 255, (16, 8, 3), dtype=np.uint8))
    shape = ShapeMesh(parts=[box_part(1, (0, 0, 0), (0.2, 0.2, 0.2)), box_part(2, (0, -0.3, 0), (0.35, 0.05, 0.35))])
    materials = [MaterialSpec("c", maps={"albedo": tex, "normal": tex}, params={"roughness": 0.2}, scale=0.1),
                 MaterialSpec("d", params={"metallic": 1.0, "roughness": 0.3, "specular": 0.2})]
    jitters = [UVTransform(1.5, 0.7, (0.1, 0.2)), None]
    camera = Camera(1.0, 0.4, 1.8, 55.0)
    renderer.beauty(boxes(7, seed=3), [MaterialSpec("x")] * 7, Camera(0.1, 0.2), None, size=16, spp=1, floor=True)
    for floor in (False, True):
        pooled = renderer.beauty(shape, materials, camera, env, size=32, spp=4, seed=5, uv_transforms=jitters,
                                 floor=floor)
        options = SceneOptions(size=32, spp=4, floor=floor, uv_transforms=tuple(jitters))
        image = np.array(mi.render(mi.load_dict(build_scene(shape, materials, env, camera, options)), spp=4, seed=5))
        hdr, _ = composite(image[..., :3], image[..., 3], "white")
        difference = np.abs(pooled.hdr - hdr)
        assert difference.mean() < 1e-4 and difference.max() < 0.02, (floor, difference.mean(), difference.max())
        assert np.allclose(pooled.alpha, np.clip(image[..., 3], 0, 1), atol=1e-4)


def test_frozen_renders_equal_traced_ones(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """`BeautyPool.render` replays recorded kernels where only the camera, the envmap's turn and
    strength or the film changed, and records anew after any upload (meshes, UVs, textures, envmap
    pixels). Over a sequence that turns the light on one shape, swaps materials, changes sizes and
    the floor, runs exact passes and frees Mitsuba objects in between, and comes back to an earlier
    shape, every frozen render equals a traced render of the same scene to float rounding; a render
    that is not recorded (`record=False`) is the traced one and leaves the recordings usable."""
    import mitsuba as mi

    from photoshape_flow.render.pool import beauty_pool
    from photoshape_flow.render.scene import SceneOptions

    gc.collect()  # other tests' objects freed now, not mid-sequence
    rng = np.random.default_rng(2)
    sky = write_exr(tmp_path / "e.exr", rng.uniform(0.1, 3.0, (16, 32, 3)).astype(np.float32))
    other = write_exr(tmp_path / "f.exr", rng.uniform(0.1, 3.0, (16, 32, 3)).astype(np.float32))
    tex = write_png(tmp_path / "t.png", rng.integers(0, 255, (16, 16, 3), dtype=np.uint8))
    shapes = [boxes(5, seed=20), boxes(3, seed=21)]
    palette = [MaterialSpec("t", maps={"albedo": tex}, scale=0.2), MaterialSpec("u", maps={"albedo": tex}, scale=0.35),
               MaterialSpec("c", params={"albedo": [0.8, 0.2, 0.1], "roughness": 0.3}),
               MaterialSpec("d", params={"albedo": [0.1, 0.5, 0.9], "metallic": 1.0, "roughness": 0.2})]
    # (shape, envmap, turn, material offset, size, floor): light turns and camera moves replay
    sequence = [(0, sky, 0.0, 0, 24, False), (0, sky, 1.5, 0, 24, False), (0, sky, 3.0, 0, 24, False),
                (0, other, 0.5, 0, 24, False), (0, other, 0.5, 1, 24, False), (0, other, 2.0, 1, 24, False),
                (1, sky, 0.0, 2, 32, False), (1, sky, 1.0, 2, 32, False), (0, sky, 0.0, 0, 24, True),
                (0, sky, 1.0, 0, 24, True), (0, sky, 2.0, 3, 24, False), (0, sky, 2.5, 3, 24, False)]
    versions = []
    for k, (which, envmap, turn, offset, size, floor) in enumerate(sequence):
        shape = shapes[which]
        materials = renderer.resolve_materials(shape, [palette[(i + offset) % 4] for i in range(len(shape.parts))])
        options = SceneOptions(size=size, spp=4, max_depth=renderer.max_depth, floor=floor,
                               max_texture_size=renderer.max_texture_size)
        pool = beauty_pool(len(shape.parts), options.max_depth, renderer.envmap_resolution)
        camera = Camera(0.3 * k, 0.2, 1.8, 50.0)
        pool.prepare(shape, materials, EnvmapSpec(envmap, 1.0 + 0.2 * k, turn), camera, options)
        versions.append(pool.version)
        frozen = pool.render(4, 1)
        traced = np.array(mi.render(pool.scene, spp=4, seed=1), dtype=np.float32)
        assert frozen.shape == traced.shape == (size, size, 4) and traced.max() > 0.0
        assert np.isfinite(frozen).all()
        assert np.abs(frozen - traced).max() <= 1e-5 * max(1.0, float(traced.max())), (k, np.abs(frozen - traced).max())
        if k in (1, 6):  # a plain trace (`record=False`) between a recording and its replays (threads
            #              accumulate samples in any order: two traces agree to rounding, not bit for bit)
            plain = pool.render(4, 1, record=False)
            assert np.abs(plain - traced).max() <= 1e-5 * max(1.0, float(traced.max()))
        renderer.part_ids(shape, camera, size)  # exact passes between renders
        if k == 4:
            gc.collect()  # Mitsuba objects freed between a recording and its replay
    assert versions[1] == versions[0] and versions[2] == versions[0]  # the light turned: a replay
    assert versions[3] != versions[2] and versions[4] != versions[3]  # other envmap pixels, other materials
    assert versions[9] == versions[8] and versions[11] == versions[10]


def test_envmap_data_matches_mitsuba_and_resamples(renderer, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    import mitsuba as mi

    from photoshape_flow.render.pool import envmap_data

    rng = np.random.default_rng(1)
    native = rng.uniform(0.0, 3.0, (8, 16, 3)).astype(np.float32)
    path = write_exr(tmp_path / "e.exr", native)
    plugin = np.array(mi.traverse(mi.load_dict({"type": "envmap", "filename": str(path)}))["data"])
    assert np.allclose(envmap_data(EnvmapSpec(path), (8, 16)), plugin)  # the plugin's own layout and values
    half = envmap_data(EnvmapSpec(path), (4, 8))[:, 1:-1]
    assert np.allclose(half, native.reshape(4, 2, 8, 2, 3).mean(axis=(1, 3)), atol=1e-5)  # area average
    assert np.allclose(envmap_data(None, (4, 8)), 1.0)  # the constant white sky
    with pytest.raises(ValueError, match="environment map file missing"):
        envmap_data(EnvmapSpec(tmp_path / "nope.exr"))


def test_casters_are_retargeted_exactly(renderer) -> None:  # type: ignore[no-untyped-def]
    """More shapes than caster slots, round robin: every map equals a fresh caster's."""
    from photoshape_flow.render.raycast import CASTER_SLOTS, RayCaster

    shapes = [boxes(3, seed=10 + n) for n in range(CASTER_SLOTS + 2)]  # equal part counts: == would compare arrays
    camera = Camera(0.3, 0.3, 1.6, 50.0)
    for order in (shapes, shapes, shapes[-2:] * 2):  # round robin (all misses), then cached ones (hits)
        for shape in order:
            ids = renderer.part_ids(shape, camera, 32)
            assert np.array_equal(ids, RayCaster(shape).cast([camera], 32)["part_ids"][0])
            assert set(np.unique(ids)) - {0} <= {p.index for p in shape.parts} and ids.max() > 0
    assert math.isfinite(float(renderer.passes(shapes[0], camera, 16, depth=True)["depth"].sum()))
