"""Refinement on a generated scene: two boxes under a studio envmap, photos made with known refinements.

The "photo" is rendered with material A adjusted by a known `Refinement` (a tint, a UV scale) at
higher spp; `fit.refine` starts from A unadjusted and must find the adjustment again.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from tests.fit.test_scene import _studio
from tests.render.conftest import write_png

from photoshape_flow.fit.refine import (
    RefineSettings,
    RegionLoss,
    choose_uv,
    like_for_like_tints,
    orientation,
    refine_parts,
    region_loss,
    uv_search,
)
from photoshape_flow.render import Camera, MaterialSpec, Refinement
from photoshape_flow.render.specs import linear_to_srgb
from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

EXPOSURE = 0.8


def test_choose_uv_keeps_identity_unless_clearly_better() -> None:
    costs = {(1.0, 0.0): 1.0, (2.0, 0.0): 0.99, (0.5, 0.0): 1.2}
    assert choose_uv(costs, margin=0.03) == (1.0, 0.0)
    assert choose_uv({**costs, (2.0, 0.0): 0.9}, margin=0.03) == (2.0, 0.0)


def test_region_loss_is_zero_at_the_target_and_grows_with_the_colour_error() -> None:
    target = (np.array([0.2, 0.1, 0.05]), np.array([0.02, 0.01, 0.01]))
    assert region_loss(target[0] / EXPOSURE, target[1] / EXPOSURE, target, EXPOSURE, 0.5) == pytest.approx(0.0)
    near = region_loss(1.1 * target[0] / EXPOSURE, target[1] / EXPOSURE, target, EXPOSURE, 0.5)
    far = region_loss(1.5 * target[0] / EXPOSURE, target[1] / EXPOSURE, target, EXPOSURE, 0.5)
    assert 0 < near < far


def test_the_differentiable_region_loss_equals_region_statistics_in_numpy() -> None:
    from photoshape_flow.render.runtime import ensure_mitsuba

    mi = ensure_mitsuba()
    rng = np.random.default_rng(0)
    labels = rng.integers(-1, 4, (37, 37))  # uneven parts, a size that is no multiple of a SIMD width
    image = rng.uniform(0.0, 1.0, (37, 37, 4)).astype(np.float32)
    parts = [5, 6, 7, 8]
    targets = {i: (rng.uniform(0.1, 0.9, 3), rng.uniform(0.01, 0.2, 3)) for i in parts}
    _, per_part = RegionLoss(mi, labels, parts, targets, 1.3, 0.5)(mi.TensorXf(image))
    expected = []
    for k, i in enumerate(parts):
        pixels = image[labels == k][:, :3].astype(np.float64)
        level = targets[i][0] + 0.02
        std = np.sqrt(np.maximum(pixels.var(axis=0), 1e-10))
        expected.append(np.sum(((1.3 * pixels.mean(axis=0) - targets[i][0]) / level) ** 2) / 3.0
                        + 0.5 * np.sum(((1.3 * std - targets[i][1]) / level) ** 2) / 3.0)
    assert np.allclose(np.array(per_part, np.float64), expected, rtol=1e-4)


def test_like_for_like_tints_recover_a_tint_where_the_photo_mixes_a_thin_part_with_the_background() -> None:
    from photoshape_flow.fit.scene import FitScene

    ids = np.zeros((40, 40), np.int64)
    ids[8:32, 6:26] = 1  # a panel
    ids[8:32, 30:32] = 2  # a leg two pixels wide: blurred, most of its photo region is background
    rgba = np.zeros((40, 40, 4), np.float32)
    rgba[ids == 1] = (0.30, 0.25, 0.20, 1.0)
    rgba[ids == 2] = (0.10, 0.08, 0.06, 1.0)
    tint = np.array([1.4, 0.9, 0.7], np.float32)
    tinted = rgba.copy()
    tinted[ids == 1, :3] *= tint
    scene = FitScene(None, None, np.zeros((40, 40, 3), np.float32), None, {1: ids == 1, 2: ids == 2}, blur=1.0,
                     background=np.array([0.9, 0.9, 0.95], np.float32))
    scene.photo_linear = scene.exposed_linear(tinted, 0.8)
    tints = like_for_like_tints(scene, rgba, ids, [1, 2], 0.8, (0.5, 2.0), 0.5)
    assert tints[1] == pytest.approx(tuple(tint), rel=1e-3)
    assert tints[2] == pytest.approx((1.0, 1.0, 1.0), rel=1e-3)
    # what reading the leg's render inside its own region against the photo's region would ask for
    own = scene.photo_linear[ids == 2].mean(0) / (0.8 * rgba[ids == 2, :3].mean(0))
    assert own.min() > 2.0
    # a part whose photo region shows mostly something else is left out
    assert 2 not in like_for_like_tints(scene, rgba, np.where(ids == 2, 0, ids), [1, 2], 0.8, (0.5, 2.0), 0.5)


def test_orientation_turns_twice_as_fast_as_stripes() -> None:
    import cv2

    y, x = np.mgrid[0:48, 0:48]
    vertical = np.sin(x / 2.0)[..., None].repeat(3, 2) * 40 + 50  # stripes along y: gradient along x
    lab = np.zeros((48, 48, 3), np.float32)
    lab[..., 0] = vertical[..., 0]
    mask = np.ones((48, 48), bool)
    a = orientation(lab, mask)
    lab[..., 0] = cv2.rotate(vertical[..., 0].astype(np.float32), cv2.ROTATE_90_CLOCKWISE)
    b = orientation(lab, mask)
    assert a[0] > 0.8 and b[0] < -0.8  # 90 degrees of stripes: the doubled angle flips the sign


@pytest.fixture(scope="module")
def boxes(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    pytest.importorskip("mitsuba")
    from photoshape_flow.render.renderer import Renderer

    folder = tmp_path_factory.mktemp("refine")
    envmap = _studio(folder / "warm-left.exr", 4, (9.0, 6.0, 3.0))
    mesh = normalise_to_unit_cube([box_part(1, (-0.3, 0.0, 0.0), (0.25, 0.45, 0.25)),
                                   box_part(2, (0.3, 0.0, 0.0), (0.25, 0.45, 0.25))])
    camera = Camera(math.radians(30), math.radians(20), 2.4, 45.0)
    y, x = np.mgrid[0:64, 0:64]
    checker = np.where(((x // 16) + (y // 16)) % 2 == 0, 200, 70).astype(np.uint8)
    texture = write_png(folder / "checker.png", np.stack([checker, (checker * 0.8).astype(np.uint8),
                                                          (checker * 0.6).astype(np.uint8)], axis=2))
    textured = MaterialSpec("checker", "fabric", maps={"albedo": texture}, params={"roughness": 0.8}, scale=0.5)
    stripes = np.where((x // 8) % 2 == 0, 210, 60).astype(np.uint8)
    striped = MaterialSpec("stripes", "wood", maps={"albedo": write_png(folder / "stripes.png", np.stack(
        [stripes, (stripes * 0.7).astype(np.uint8), (stripes * 0.5).astype(np.uint8)], axis=2))},
        params={"roughness": 0.7}, scale=0.5)
    plain = MaterialSpec("plain", "plastic", params={"albedo": [0.45, 0.45, 0.5], "roughness": 0.5}, scale=None)
    return Renderer(), mesh, camera, envmap, textured, plain, striped


def _photo_scene(boxes, materials, size: int = 64):  # type: ignore[no-untyped-def]
    from photoshape_flow.fit.scene import FitScene, FrameRenderer

    renderer, mesh, camera, envmap, *_ = boxes
    photo_frame = FrameRenderer(renderer, size, 64)
    photo = linear_to_srgb(EXPOSURE * photo_frame.render(mesh, materials, camera, envmap))
    photo = (photo * 255 + 0.5).astype(np.uint8)
    ids = photo_frame.part_ids(mesh, camera)
    labels = np.roll(ids, 1, axis=1)  # alignment is never exact
    return FitScene.from_photo(mesh, camera, photo, labels, [1, 2], foreground=ids > 0)


def test_refinement_recovers_a_known_albedo_tint(boxes) -> None:  # type: ignore[no-untyped-def]
    from dataclasses import replace

    from photoshape_flow.fit.scene import FrameRenderer

    renderer, mesh, camera, envmap, textured, plain, _ = boxes
    tint = (1.4, 0.9, 0.7)
    scene = _photo_scene(boxes, [replace(plain, refinement=Refinement(tint=tint)), plain])
    settings = RefineSettings(uv_scales=(1.0,), uv_rotations=(0.0,))  # the default 8 steps
    result = refine_parts(FrameRenderer(renderer, 64, 4), scene, [plain, plain], [1, 2], envmap, EXPOSURE,
                          settings)
    assert set(result) == {1, 2}
    assert result[1].refinement.tint == pytest.approx(tint, rel=0.12), result[1]
    assert result[2].refinement.tint == pytest.approx((1.0, 1.0, 1.0), rel=0.12), result[2]
    assert result[1].loss_after < 0.25 * result[1].loss_before


def test_uv_search_recovers_a_known_texture_scale(boxes) -> None:  # type: ignore[no-untyped-def]
    from dataclasses import replace

    from photoshape_flow.fit.scene import FrameRenderer

    renderer, mesh, camera, envmap, textured, plain, _ = boxes
    scene = _photo_scene(boxes, [replace(textured, refinement=Refinement(uv_scale=2.0)), plain])
    found = uv_search(FrameRenderer(renderer, 64, 8), scene, [textured, plain], [1, 2], envmap, EXPOSURE,
                      RefineSettings(uv_rotations=(0.0,)))
    assert set(found) == {1}  # the plain part has no texture to place
    (scale, rotation), costs = found[1]
    assert (scale, rotation) == (2.0, 0.0) and costs["chosen"] < costs["identity"]


def test_refined_textures_apply_tint_and_roughness_in_the_renderer(tmp_path: Path) -> None:
    from photoshape_flow.render.scene import material_textures

    spec = MaterialSpec("m", params={"albedo": [0.5, 0.5, 0.5], "roughness": 0.6}, scale=None,
                        refinement=Refinement(tint=(2.0, 1.0, 0.5), roughness_scale=2.0))
    data = material_textures(spec)
    base = material_textures(MaterialSpec("m", params={"albedo": [0.5, 0.5, 0.5], "roughness": 0.6}, scale=None))
    assert data["base_color"][0, 0] == pytest.approx(base["base_color"][0, 0] * np.array([2.0, 1.0, 0.5]), rel=1e-5)
    assert float(data["roughness"][0, 0, 0]) == 1.0  # clipped: 0.6 x 2


def test_uv_search_recovers_a_known_texture_rotation(boxes) -> None:  # type: ignore[no-untyped-def]
    """Stripes turned by 90 degrees are found among four rotations (identity would tie otherwise)."""
    from dataclasses import replace

    from photoshape_flow.fit.scene import FrameRenderer

    renderer, mesh, camera, envmap, _, plain, striped = boxes
    scene = _photo_scene(boxes, [replace(striped, refinement=Refinement(uv_rotation=math.pi / 2)), plain])
    found = uv_search(FrameRenderer(renderer, 64, 8), scene, [striped, plain], [1, 2], envmap, EXPOSURE,
                      RefineSettings(uv_scales=(1.0,)))
    (scale, rotation), costs = found[1]
    assert (scale, rotation) == (1.0, pytest.approx(math.pi / 2)) and costs["chosen"] < costs["identity"]
