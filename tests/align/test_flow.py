"""Silhouette flow: known motions are recovered, nearest-label warping never invents labels."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from photoshape_flow.align.flow import (
    FlowParams,
    coordinate_encoding,
    flow_warp,
    horn_schunck_flow,
    sdf_uint8,
    signed_distance,
    silhouette_flow,
    warp_labels,
)

SIZE = 96


def chair_labels(size: int = SIZE) -> np.ndarray:
    """A frontal chair: back (1), seat (2), two legs (3), arm rests (4); ~0.6 of the frame."""
    ids = np.zeros((size, size), np.uint16)
    s = size / 96.0

    def box(x0: float, y0: float, x1: float, y1: float, label: int) -> None:
        cv2.rectangle(ids, (int(x0 * s), int(y0 * s)), (int(x1 * s), int(y1 * s)), label, -1)

    box(30, 12, 66, 46, 1)
    box(26, 46, 70, 54, 2)
    box(28, 54, 32, 84, 3)
    box(64, 54, 68, 84, 3)
    box(22, 38, 27, 46, 4)
    box(69, 38, 74, 46, 4)
    return ids


def moved(labels: np.ndarray, dx: float, dy: float, scale: float) -> np.ndarray:
    size = labels.shape[0]
    matrix = cv2.getRotationMatrix2D((size / 2, size / 2), 0.0, scale)
    matrix[:, 2] += (dx, dy)
    return cv2.warpAffine(labels, matrix, (size, size), flags=cv2.INTER_NEAREST)


def accuracy(pred: np.ndarray, gt: np.ndarray) -> float:
    fg = gt > 0
    return float((pred[fg] == gt[fg]).mean())


@pytest.mark.parametrize("method", ["dis-sdf", "hs-sdf", "hs-coords", "deepflow-sdf"])
def test_flow_recovers_translation_and_scale(method: str) -> None:
    coarse = chair_labels()
    target = moved(coarse, dx=4.0, dy=-3.0, scale=1.08)
    before = accuracy(coarse, target)
    warped, flow = flow_warp(coarse, target > 0, FlowParams(method=method))
    after = accuracy(warped, target)
    assert flow.shape == (SIZE, SIZE, 2)
    assert before < 0.7
    assert after > 0.85
    assert after > before + 0.2
    # inside the back (a large region) the flow is close to the true inverse motion
    ys, xs = np.nonzero(target == 1)
    centre = (SIZE / 2, SIZE / 2)
    true_dx = (xs - 4.0 - centre[0]) / 1.08 + centre[0] - xs
    true_dy = (ys + 3.0 - centre[1]) / 1.08 + centre[1] - ys
    err = np.hypot(flow[ys, xs, 0] - true_dx, flow[ys, xs, 1] - true_dy)
    assert np.median(err) < 2.0


def test_identity_and_empty_masks_give_zero_flow() -> None:
    coarse = chair_labels()
    assert not silhouette_flow(coarse > 0, coarse > 0, FlowParams(method="identity")).any()
    assert not silhouette_flow(np.zeros_like(coarse, bool), coarse > 0).any()
    warped, _ = flow_warp(coarse, np.zeros_like(coarse, bool))
    assert np.array_equal(warped, coarse)


def test_same_silhouette_barely_moves() -> None:
    coarse = chair_labels()
    warped, flow = flow_warp(coarse, coarse > 0, FlowParams(method="dis-sdf"))
    assert accuracy(warped, coarse) > 0.97
    assert np.median(np.abs(flow)) < 0.5


def test_warp_labels_never_invents_labels() -> None:
    rng = np.random.default_rng(0)
    labels = rng.choice(np.array([0, 3, 7, 1000], np.uint16), size=(40, 50))
    flow = rng.normal(0, 6.0, (40, 50, 2)).astype(np.float32)  # fractional, partly out of the image
    warped = warp_labels(labels, flow)
    assert warped.dtype == labels.dtype
    assert set(np.unique(warped)) <= {0, 3, 7, 1000}
    # integer flow is an exact lookup
    shift = np.zeros((40, 50, 2), np.float32)
    shift[..., 0] = 2
    assert np.array_equal(warp_labels(labels, shift)[:, :-2], labels[:, 2:])
    assert not warp_labels(labels, shift)[:, -2:].any()


def test_flow_warp_keeps_the_label_set() -> None:
    coarse = chair_labels()
    target = moved(coarse, dx=-5.0, dy=2.0, scale=0.9)
    for method in ("dis-sdf", "hs-sdf"):
        warped, _ = flow_warp(coarse, target > 0, FlowParams(method=method))
        assert set(np.unique(warped)) <= set(np.unique(coarse))


def test_encodings() -> None:
    mask = np.zeros((20, 20), bool)
    mask[5:15, 5:15] = True
    sdf = signed_distance(mask)
    assert sdf[10, 10] > 4 and sdf[0, 0] < -6 and abs(sdf[5, 10]) <= 1.0
    enc = sdf_uint8(mask, range_px=5)
    assert enc.dtype == np.uint8 and enc[10, 10] == 255 and enc[0, 0] == 1
    coords = coordinate_encoding(mask)
    assert np.allclose(coords[10, 10], 1.0)
    assert coords[0, 19, 0] == 0 and coords[0, 19, 1] == pytest.approx(1.0) and coords[19, 0, 2] == pytest.approx(1.0)


def test_horn_schunck_multichannel_shift() -> None:
    rng = np.random.default_rng(1)
    base = cv2.GaussianBlur(rng.random((64, 64, 3)).astype(np.float32), (0, 0), 3.0)
    shifted = np.roll(base, (2, -3), axis=(0, 1))  # content moves down 2, left 3
    flow = horn_schunck_flow(shifted, base, alpha=0.02, levels=4, warps=4, iterations=80, median=0)
    inner = flow[16:48, 16:48]
    assert np.median(inner[..., 0]) == pytest.approx(3.0, abs=0.5)
    assert np.median(inner[..., 1]) == pytest.approx(-2.0, abs=0.5)
    with pytest.raises(ValueError):
        horn_schunck_flow(base, base[:10])
