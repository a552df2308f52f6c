"""Camera convention of contributing.md: pure numpy, no Mitsuba needed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from photoshape_flow.render.camera import Camera


def test_position_formula_and_axes() -> None:
    cam = Camera(azimuth=0.0, elevation=0.0, distance=2.0, fov=50.0)
    assert np.allclose(cam.position, [0, 0, 2])
    assert np.allclose(Camera(math.pi / 2, 0.0, 3.0, 50.0).position, [3, 0, 0])  # azimuth towards +x
    assert np.allclose(Camera(0.0, math.pi / 2, 1.5, 50.0).position, [0, 1.5, 0], atol=1e-12)
    az, el, d = 0.7, 0.3, 1.6
    expected = d * np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
    assert np.allclose(Camera(az, el, d, 55.0).position, expected)


def test_to_world_is_a_look_at_rotation() -> None:
    cam = Camera(1.1, 0.4, 1.7, 55.0)
    m = cam.to_world()
    r = m[:3, :3]
    assert np.allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(r), 1.0)
    assert np.allclose(m[:3, 3], cam.position)
    assert np.allclose(m[:3, 2], -cam.position / np.linalg.norm(cam.position))  # looks at the origin
    assert m[1, 1] > 0  # +y up
    straight_down = Camera(0.3, math.pi / 2, 2.0).to_world()  # degenerate look_at still a rotation
    assert np.allclose(straight_down[:3, :3].T @ straight_down[:3, :3], np.eye(3), atol=1e-9)


def test_project_centre_edges_and_orientation() -> None:
    size = 64
    cam = Camera(0.0, 0.0, 2.0, 50.0)
    half_width = 2.0 * math.tan(math.radians(25.0))
    pts = np.array([[0, 0, 0], [half_width, 0, 0], [-half_width, 0, 0], [0, half_width, 0], [0.1, 0.0, 1.0]])
    pix, depth = cam.project(pts, size)
    assert np.allclose(pix[0], [32, 32])
    assert np.allclose(pix[1], [64, 32])  # world +x is image right (seen from +z)
    assert np.allclose(pix[2], [0, 32])
    assert np.allclose(pix[3], [32, 0])  # world +y is image up (row 0)
    assert np.allclose(depth[:4], 2.0) and np.isclose(depth[4], 1.0)


def test_pixel_rays_match_project() -> None:
    cam = Camera(-0.8, 0.35, 1.5, 52.0)
    size = 16
    rays = cam.pixel_rays(size)
    pts = cam.position + 1.3 * rays.reshape(-1, 3)
    pix, _ = cam.project(pts, size)
    jj, ii = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    assert np.allclose(pix[:, 0], jj.ravel()) and np.allclose(pix[:, 1], ii.ravel())


def test_dict_round_trip_and_replace() -> None:
    cam = Camera(0.25, -0.1, 1.4, 57.0)
    assert Camera.from_dict(cam.to_dict()) == cam
    assert cam.replace(fov=50.0).fov == 50.0
    with pytest.raises(KeyError):
        Camera.from_dict({"azimuth": 0.0})
