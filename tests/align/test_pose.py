"""Camera refinement by silhouette (`align.pose`): a perturbed pose moves back toward the photo's camera."""

from __future__ import annotations

import math

import pytest

from photoshape_flow.align.fine import silhouette_iou
from photoshape_flow.align.pose import MAX_ANGLE_DEG, refine_camera
from photoshape_flow.render import Camera
from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def frame():  # type: ignore[no-untyped-def]
    pytest.importorskip("mitsuba")
    from photoshape_flow.fit.scene import FrameRenderer
    from photoshape_flow.render import Renderer

    # an L of two boxes: no symmetry a wrong azimuth or elevation could hide behind
    mesh = normalise_to_unit_cube([box_part(1, (0.0, 0.0, 0.0), (0.5, 0.12, 0.3)),
                                   box_part(2, (0.35, 0.4, -0.2), (0.15, 0.3, 0.1))])
    return FrameRenderer(Renderer(), 64, 1), mesh


def _error(a: Camera, b: Camera) -> tuple[float, float, float]:
    turn = abs((a.azimuth - b.azimuth + math.pi) % (2 * math.pi) - math.pi)
    return math.degrees(turn), math.degrees(abs(a.elevation - b.elevation)), abs(math.log(a.distance / b.distance))


def test_a_perturbed_pose_moves_back_toward_the_photo_camera(frame) -> None:  # type: ignore[no-untyped-def]
    renderer, mesh = frame
    truth = Camera(math.radians(35.0), math.radians(20.0), 2.0, 40.0)
    target = renderer.part_ids(mesh, truth) > 0
    start = Camera(math.radians(41.0), math.radians(15.0), 2.8, 40.0)
    refined = refine_camera(lambda c: renderer.part_ids(mesh, c), start, target)
    assert refined.iou_after > refined.iou_before
    assert refined.iou_after == pytest.approx(silhouette_iou(renderer.part_ids(mesh, refined.camera), target))
    before, after = _error(start, truth), _error(refined.camera, truth)
    assert after[0] < before[0] and after[1] < before[1] and after[2] < before[2]
    assert max(after[:2]) <= 2.0


def test_the_search_stays_near_the_coarse_pose(frame) -> None:  # type: ignore[no-untyped-def]
    renderer, mesh = frame
    target = renderer.part_ids(mesh, Camera(math.radians(120.0), math.radians(20.0), 2.0, 40.0)) > 0
    start = Camera(math.radians(35.0), math.radians(20.0), 2.0, 40.0)  # 85 degrees away: out of reach
    refined = refine_camera(lambda c: renderer.part_ids(mesh, c), start, target)
    turn, elevation, _ = _error(refined.camera, start)
    assert turn <= MAX_ANGLE_DEG + 1e-6 and elevation <= MAX_ANGLE_DEG + 1e-6


def test_a_photo_the_coarse_pose_already_fits_is_left_alone(frame) -> None:  # type: ignore[no-untyped-def]
    renderer, mesh = frame
    camera = Camera(math.radians(35.0), math.radians(20.0), 2.0, 40.0)
    refined = refine_camera(lambda c: renderer.part_ids(mesh, c), camera, renderer.part_ids(mesh, camera) > 0)
    assert refined.camera == camera and refined.iou_before == pytest.approx(1.0)
