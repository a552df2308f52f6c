"""Exact part-ID maps, camera round trip, depth/normals and viewpoint sweeps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.testing import box_part, procedural_chair, quad_part

pytestmark = pytest.mark.render


def two_quads() -> ShapeMesh:
    left = quad_part(1, [[-0.5, -0.5, 0], [0, -0.5, 0], [0, 0.5, 0], [-0.5, 0.5, 0]])
    right = quad_part(2, [[0, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [0, 0.5, 0]])
    return ShapeMesh(parts=[left, right])


def expected_two_quads(camera: Camera, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Analytic ids at pixel centres for a head-on camera, and a mask of pixels near an edge."""
    f = camera.focal(size)
    centres = np.arange(size) + 0.5
    x = (centres - size / 2) / f * camera.distance  # world x of each column's centre ray at z = 0
    y = (size / 2 - centres) / f * camera.distance
    xx, yy = np.meshgrid(x, y)
    inside = (np.abs(xx) < 0.5) & (np.abs(yy) < 0.5)
    ids = np.where(inside, np.where(xx < 0, 1, 2), 0)
    px = camera.distance / f  # one pixel in world units at z = 0
    near_edge = np.zeros_like(inside)
    for edge in (-0.5, 0.0, 0.5):
        near_edge |= (np.abs(xx - edge) < px) & (np.abs(yy) < 0.5 + px)
        near_edge |= (np.abs(yy - edge) < px) & (np.abs(xx) < 0.5 + px) & (edge != 0.0)
    return ids, near_edge


@pytest.mark.parametrize("size", [32, 63])
def test_part_ids_exact_on_two_quads(renderer, size: int) -> None:  # type: ignore[no-untyped-def]
    shape = two_quads()
    camera = Camera(0.0, 0.0, 2.0, 50.0)
    ids = renderer.part_ids(shape, camera, size)
    assert ids.dtype == np.uint16 and ids.shape == (size, size)
    assert set(np.unique(ids).tolist()) <= {0, 1, 2}
    expected, near_edge = expected_two_quads(camera, size)
    assert np.array_equal(ids[~near_edge], expected[~near_edge])
    assert (~near_edge).sum() > 0.8 * size * size


def test_mitsuba_aov_route_agrees(renderer) -> None:  # type: ignore[no-untyped-def]
    shape = procedural_chair(target_faces=2000)
    for camera in (Camera(0.6, 0.3, 2.0, 50.0), Camera(-2.0, -0.1, 1.5, 57.0)):
        rays = renderer.part_ids(shape, camera, 48)
        aov = renderer.part_ids(shape, camera, 48, method="aov")
        assert np.unique(aov).tolist() == np.unique(rays).tolist()
        assert (rays == aov).mean() > 0.995  # pixel-centre ties at edges may differ by float rounding
        assert set(np.unique(rays).tolist()) <= {0} | {p.index for p in shape.parts}


def test_camera_round_trip_marker(renderer) -> None:  # type: ignore[no-untyped-def]
    point = np.array([0.21, 0.12, -0.17])
    marker = box_part(1, tuple(point), (0.015, 0.015, 0.015))
    backdrop = quad_part(2, [[-3, -3, -1.5], [3, -3, -1.5], [3, 3, -1.5], [-3, 3, -1.5]])
    shape = ShapeMesh(parts=[marker, backdrop])
    size = 64
    for camera in (Camera(0.5, 0.35, 2.0, 50.0), Camera(-0.4, -0.15, 1.6, 58.0)):
        ids = renderer.part_ids(shape, camera, size)
        rows, cols = np.nonzero(ids == 1)
        assert len(rows) > 0
        found = np.array([cols.mean() + 0.5, rows.mean() + 0.5])
        pixel, depth = camera.project(point[None], size)
        assert np.linalg.norm(found - pixel[0]) < 0.75
        out = renderer.passes(shape, camera, size, depth=True)
        r, c = int(pixel[0, 1]), int(pixel[0, 0])
        # the marker's near side: in front of its centre, within its half-diagonal plus half a pixel
        assert depth[0] - 0.06 < out["depth"][r, c] < depth[0]


def test_normals_and_depth_of_a_plane(renderer) -> None:  # type: ignore[no-untyped-def]
    plane = quad_part(1, [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    camera = Camera(0.0, 0.0, 2.0, 40.0)
    out = renderer.passes(ShapeMesh(parts=[plane]), camera, 32, normals=True, depth=True, shaded=True)
    assert out["mask"].all()
    assert np.allclose(out["depth"], 2.0, atol=1e-4)  # viewing-axis depth, not ray length
    assert np.allclose(out["normals"], [0, 0, 1], atol=1e-5)
    # headlight: brightest where the view ray is perpendicular to the plane
    assert out["shaded"][16, 16] > out["shaded"][0, 0] > 0.1


def test_sweep_matches_single_renders(renderer) -> None:  # type: ignore[no-untyped-def]
    shape = procedural_chair(target_faces=3000)
    cameras = [Camera(az, el, 2.0, 50.0) for az in np.linspace(0, 2 * math.pi, 5, endpoint=False) for el in (0.0, 0.5)]
    cameras.append(Camera(0.3, 0.2, 1.4, 60.0))
    result = renderer.sweep(shape, cameras, size=40, shaded=True)
    assert result.part_ids.shape == (len(cameras), 40, 40) and result.part_ids.dtype == np.uint16
    assert result.shaded is not None and result.shaded.shape == (len(cameras), 40, 40)
    for i, camera in enumerate(cameras):
        assert np.array_equal(result.part_ids[i], renderer.part_ids(shape, camera, 40))
    background = result.part_ids == 0
    assert np.all(result.shaded[background] == 1.0)
    assert result.shaded[~background].min() >= 0.1 and result.shaded[~background].max() <= 0.9 + 1e-6
    assert renderer.sweep(shape, cameras[:3], size=40, shaded=False).shaded is None


def test_sweeps_reuse_kernels_across_shapes(renderer) -> None:  # type: ignore[no-untyped-def]
    import drjit as dr

    def launched(shape: ShapeMesh, views: int) -> set[str]:
        cameras = [Camera(0.4 * i, 0.2, 2.0, 50.0) for i in range(views)]
        dr.kernel_history_clear()
        renderer.sweep(shape, cameras, size=24, shaded=True)
        history = dr.kernel_history()
        return {k["hash"] for k in history if k["type"] == dr.KernelType.JIT and k["size"] == views * 24 * 24}

    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        first = launched(procedural_chair(target_faces=1000), 3)
        second = launched(two_quads(), 5)  # other geometry, part count and view count
    assert first and second <= first
