"""Fine alignment of one pair (coarse -> flow -> CRF), its metrics, and the coarse part map."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from photoshape_flow.align.crf import CRFParams
from photoshape_flow.align.fine import FineParams, align_pair, part_label_accuracy, silhouette_iou
from photoshape_flow.align.flow import FlowParams
from photoshape_flow.align.partmap import (
    crop_square,
    exemplar_at,
    fit_part_map,
    render_coarse_part_map,
    square_box,
    zoom_to_fit,
)
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

SIZE = 96


def chair(size: int, shift: tuple[float, float] = (0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    """Part IDs of a frontal chair (back 1, seat 2, legs 3) on a size^2 canvas."""
    ids = np.zeros((size, size), np.uint16)
    s = size / 96.0 * scale
    ox, oy = size / 2 + shift[0], size / 2 + shift[1]

    def box(x0: float, y0: float, x1: float, y1: float, label: int) -> None:
        p0 = (int(round(ox + (x0 - 48) * s)), int(round(oy + (y0 - 48) * s)))
        p1 = (int(round(ox + (x1 - 48) * s)), int(round(oy + (y1 - 48) * s)))
        cv2.rectangle(ids, p0, p1, label, -1)

    box(30, 10, 66, 46, 1)
    box(26, 46, 70, 54, 2)
    box(28, 54, 32, 86, 3)
    box(64, 54, 68, 86, 3)
    return ids


def photo(gt: np.ndarray, seed: int = 0) -> np.ndarray:
    """A 'photo' of a part map: one colour per part with noise, white background."""
    rng = np.random.default_rng(seed)
    palette = np.array([[255, 255, 255], [120, 40, 30], [200, 170, 120], [40, 40, 45]], np.float32)
    rgb = palette[gt] + rng.normal(0, 4.0, (*gt.shape, 3))
    rgb[gt == 0] = 255
    return np.clip(rgb, 0, 255).astype(np.uint8)


def test_align_pair_improves_at_each_step() -> None:
    gt = chair(SIZE, shift=(3, -2), scale=1.06)
    coarse = chair(SIZE)
    params = FineParams(size=SIZE, crf=CRFParams(theta_pos=0.1))
    result = align_pair(coarse, photo(gt), gt > 0, params)
    acc = [part_label_accuracy(m, gt) for m in (result.coarse, result.flow, result.crf)]
    assert acc[0] < 0.8
    assert acc[1] > acc[0] + 0.1
    assert acc[2] >= acc[1]
    assert acc[2] > 0.95
    assert result.iou_coarse < result.iou_flow <= result.iou_crf + 0.02
    assert result.iou_crf > 0.95
    assert result.flow_field is not None and result.flow_field.shape == (SIZE, SIZE, 2)
    for labels in (result.flow, result.crf):
        assert labels.dtype == np.uint16
        assert set(np.unique(labels)) <= {0, 1, 2, 3}


def test_align_pair_resizes_to_the_working_resolution() -> None:
    gt = chair(2 * SIZE, shift=(4, 0))
    result = align_pair(chair(2 * SIZE), photo(gt), (gt > 0).astype(np.uint8) * 255, FineParams(size=SIZE))
    assert result.coarse.shape == result.flow.shape == result.crf.shape == (SIZE, SIZE)
    small_gt = cv2.resize(gt, (SIZE, SIZE), interpolation=cv2.INTER_NEAREST)
    assert part_label_accuracy(result.crf, small_gt) > part_label_accuracy(result.coarse, small_gt)


def test_identity_flow_keeps_the_coarse_map() -> None:
    gt = chair(SIZE, shift=(3, 0))
    params = FineParams(size=SIZE, flow=FlowParams(method="identity"))
    result = align_pair(chair(SIZE), photo(gt), gt > 0, params)
    assert np.array_equal(result.flow, result.coarse)


def test_part_label_accuracy_counts_ground_truth_foreground_only() -> None:
    gt = np.array([[0, 1, 1], [2, 2, 0]], np.uint16)
    pred = np.array([[5, 1, 0], [2, 2, 2]], np.uint16)
    assert part_label_accuracy(pred, gt) == pytest.approx(3 / 4)
    assert math.isnan(part_label_accuracy(pred, np.zeros_like(gt)))
    with pytest.raises(ValueError):
        part_label_accuracy(pred[:1], gt)


def test_silhouette_iou() -> None:
    a = np.zeros((4, 4), np.uint16)
    a[:2, :2] = 3
    b = np.zeros((4, 4), bool)
    b[:2, :] = True
    assert silhouette_iou(a, b) == pytest.approx(0.5)
    assert silhouette_iou(np.zeros((2, 2)), np.zeros((2, 2), bool)) == 1.0


# -- partmap --------------------------------------------------------------------------------------


def test_square_box_and_crop() -> None:
    mask = np.zeros((20, 30), bool)
    mask[5:9, 10:22] = True  # 4 tall, 12 wide
    assert square_box(mask) == (10, 1, 12)
    assert square_box(np.zeros((3, 3), bool)) is None
    crop = crop_square(np.arange(6).reshape(2, 3), -1, 0, 3, fill=-1)
    assert crop.tolist() == [[-1, 0, 1], [-1, 3, 4], [-1, -1, -1]]


def test_fit_part_map_is_tight_and_nearest() -> None:
    ids = np.zeros((100, 100), np.uint16)
    ids[20:60, 30:50] = 4
    ids[60:80, 30:50] = 9
    fitted = fit_part_map(ids, 30)
    assert fitted.shape == (30, 30) and fitted.dtype == np.uint16
    assert set(np.unique(fitted)) == {0, 4, 9}
    rows = np.flatnonzero(fitted.any(axis=1))
    assert rows[0] == 0 and rows[-1] == 29  # the longer side spans the frame
    cols = np.flatnonzero(fitted.any(axis=0))
    assert abs((cols[0] + cols[-1]) / 2 - 14.5) <= 1  # centred on the shorter side
    # a target box (exemplar crop with a margin) places the same square inside the frame
    boxed = fit_part_map(ids, 30, target_box=(5, 5, 20))
    assert square_box(boxed > 0) == pytest.approx((5, 5, 20), abs=1)
    with pytest.raises(ValueError):
        fit_part_map(np.zeros((5, 5), np.uint16), 8)


def two_box_shape() -> ShapeMesh:
    return normalise_to_unit_cube([
        box_part(1, (0.0, 0.4, 0.0), (0.5, 0.1, 0.4), "seat"),
        box_part(2, (0.0, -0.2, 0.0), (0.1, 0.5, 0.1), "post"),
    ])


def test_zoom_to_fit_fills_the_frame() -> None:
    shape = two_box_shape()
    camera = Camera(0.4, 0.3, 2.5, 50.0)
    zoomed = zoom_to_fit(shape, camera, margin=0.0)
    assert zoomed.fov < camera.fov
    assert (zoomed.azimuth, zoomed.elevation, zoomed.distance) == (camera.azimuth, camera.elevation, camera.distance)
    vertices = np.concatenate([p.vertices for p in shape.parts])
    xy, _ = zoomed.project(vertices, 100)
    assert np.abs(xy - 50).max() == pytest.approx(50, abs=1e-6)
    # a camera too close for the shape to fit widens instead
    assert zoom_to_fit(shape, Camera(0.4, 0.3, 0.9, 30.0)).fov > 30.0


def test_exemplar_at() -> None:
    rgb = np.full((40, 40, 3), 255, np.uint8)
    rgb[10:30, 10:30] = 20
    mask = np.zeros((40, 40), np.uint8)
    mask[10:30, 10:30] = 255
    small, fg = exemplar_at(rgb, mask, 20)
    assert small.shape == (20, 20, 3) and fg.shape == (20, 20) and fg.dtype == bool
    assert fg[5:15, 5:15].all() and not fg[:4].any()
    grey, fg16 = exemplar_at(rgb[..., 0], mask.astype(np.uint16), 40)
    assert grey.shape == (40, 40, 3) and fg16.sum() == 400


@pytest.mark.render
def test_render_coarse_part_map_matches_a_direct_render() -> None:
    pytest.importorskip("mitsuba")
    from photoshape_flow.render.renderer import Renderer

    renderer = Renderer()
    shape = two_box_shape()
    camera = Camera(0.6, 0.25, 2.0, 50.0)
    coarse = render_coarse_part_map(renderer, shape, camera, size=64)
    assert coarse.shape == (64, 64) and coarse.dtype == np.uint16
    assert set(np.unique(coarse)) == {0, 1, 2}
    assert square_box(coarse > 0) == (0, 0, 64)  # tight like the exemplar crop
    direct = fit_part_map(renderer.part_ids(shape, camera, size=512), 64)
    # the two differ only by sampling: on label edges, never in the interior of a region
    edge = np.zeros(direct.shape, bool)
    for axis in (0, 1):
        change = np.diff(direct.astype(np.int32), axis=axis) != 0
        lo = [slice(None), slice(None)]
        hi = [slice(None), slice(None)]
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        edge[tuple(lo)] |= change
        edge[tuple(hi)] |= change
    edge = cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert (direct == coarse).mean() > 0.9
    assert (direct[~edge] == coarse[~edge]).mean() > 0.995
