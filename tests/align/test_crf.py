"""Dense CRF: unaries as in the original, both backends against an exact O(N^2) mean field."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.align.crf import (
    CRFParams,
    crf_refine,
    dense_crf,
    fallback_meanfield,
    label_probabilities,
    pydensecrf_available,
    reference_meanfield,
    white_pixels,
)

SIDE = 12


def scene(seed: int = 0, flip: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """12 x 12: two coloured parts over a white floor band, and labels with `flip` of them random."""
    rng = np.random.default_rng(seed)
    rgb = np.zeros((SIDE, SIDE, 3), np.uint8)
    rgb[:, :6] = (200, 60, 40)
    rgb[:, 6:] = (40, 80, 200)
    rgb[8:] = 255
    gt = np.where(np.arange(SIDE)[None, :] < 6, 1, 2).repeat(SIDE, axis=0).astype(np.uint16)
    gt[8:] = 0
    noisy = gt.copy()
    flips = rng.random((SIDE, SIDE)) < flip
    noisy[flips] = rng.choice(np.array([0, 1, 2], np.uint16), flips.sum())
    return rgb, gt, noisy


# wider kernels than the defaults so that a 12 x 12 image has real interactions
PARAMS = [
    CRFParams(theta_pos=0.25, theta_lab=(10.0, 10.0, 10.0), w_appearance=3.0, iterations=10),
    CRFParams(theta_pos=0.25, theta_lab=(10.0, 10.0, 10.0), w_appearance=3.0, w_smooth=1.0, smooth_sxy=2.0),
    CRFParams(theta_pos=0.25),  # the defaults otherwise (Lab 5, Potts 6, 20 iterations)
]


def test_label_probabilities_follow_the_original() -> None:
    labels = np.array([[0, 5], [9, 0]], np.uint16)
    background = np.array([[True, True], [False, False]])
    probs = label_probabilities(labels, background, np.array([0, 5, 9]), bg_logit=3.0)
    assert probs.shape == (3, 2, 2)
    assert np.allclose(probs.sum(axis=0), 1.0)
    e = np.e
    # background, unlabelled: logit 3 on background only
    assert probs[:, 0, 0] == pytest.approx([e**3 / (e**3 + 2), 1 / (e**3 + 2), 1 / (e**3 + 2)], rel=1e-5)
    # background but warped to part 5: logits (3, 1, 0)
    assert probs[:, 0, 1] == pytest.approx(np.exp([3, 1, 0]) / np.exp([3, 1, 0]).sum(), rel=1e-5)
    # foreground warped to part 9: softmax of one-hot
    assert probs[:, 1, 0] == pytest.approx(np.exp([0, 0, 1]) / np.exp([0, 0, 1]).sum(), rel=1e-5)
    # foreground the warp left unlabelled: uniform
    assert probs[:, 1, 1] == pytest.approx([1 / 3] * 3, rel=1e-5)
    with pytest.raises(ValueError):
        label_probabilities(labels, background, np.array([0, 5]))


def test_reference_meanfield_cleans_noise() -> None:
    rgb, gt, noisy = scene()
    probs = label_probabilities(noisy, rgb.min(axis=2) > 240, np.array([0, 1, 2]))
    q = reference_meanfield(probs, rgb, PARAMS[0])
    assert np.allclose(q.sum(axis=0), 1.0, atol=1e-5)
    assert (q.argmax(0) == gt).mean() > (probs.argmax(0) == gt).mean() + 0.1


@pytest.mark.parametrize("params", PARAMS)
def test_pydensecrf_matches_brute_force(params: CRFParams) -> None:
    pytest.importorskip("pydensecrf.densecrf")
    from photoshape_flow.align.crf import pydensecrf_meanfield

    for seed in range(3):
        rgb, _, noisy = scene(seed)
        probs = label_probabilities(noisy, rgb.min(axis=2) > 240, np.array([0, 1, 2]))
        exact = reference_meanfield(probs, rgb, params)
        lattice = pydensecrf_meanfield(probs, rgb, params)
        # the permutohedral lattice approximates the Gaussian kernels: close marginals, same labels
        assert np.abs(lattice - exact).mean() < 0.01
        assert np.abs(lattice - exact).max() < 0.08
        assert (lattice.argmax(0) == exact.argmax(0)).mean() >= 0.97


@pytest.mark.parametrize("params", PARAMS)
def test_fallback_agrees_with_brute_force(params: CRFParams) -> None:
    for seed in range(3):
        rgb, gt, noisy = scene(seed)
        probs = label_probabilities(noisy, rgb.min(axis=2) > 240, np.array([0, 1, 2]))
        exact = reference_meanfield(probs, rgb, params).argmax(0)
        fast = fallback_meanfield(probs, rgb, params)
        assert np.allclose(fast.sum(axis=0), 1.0, atol=1e-4)
        assert (fast.argmax(0) == exact).mean() >= 0.95
        assert (fast.argmax(0) == gt).mean() > (probs.argmax(0) == gt).mean()


def test_fallback_on_a_larger_image_with_many_labels() -> None:
    """More than four labels (dtFilter's channel limit) and a real size."""
    rng = np.random.default_rng(3)
    size, n = 64, 7
    gt = (np.arange(size)[None, :] * n // size).repeat(size, axis=0).astype(np.uint16)
    palette = rng.integers(0, 230, (n, 3)).astype(np.uint8)
    rgb = palette[gt]
    noisy = gt.copy()
    flips = rng.random(gt.shape) < 0.3
    noisy[flips] = rng.integers(1, n, flips.sum())
    fg = np.ones_like(gt, bool)
    fg[:, :size // n] = False  # label 0's band is background
    noisy[~fg] = 0
    gt[~fg] = 0
    rgb[~fg] = 255
    out = crf_refine(noisy, rgb, fg, CRFParams(backend="fallback", label_logit=1.0))
    assert (out == gt).mean() > (noisy == gt).mean() + 0.15
    assert (out == gt).mean() > 0.95


def test_crf_refine_maps_back_to_part_ids() -> None:
    rgb, gt, noisy = scene()
    ids = np.array([0, 4, 11], np.uint16)
    warped = ids[noisy]
    fg = gt > 0
    for backend in ("fallback", "auto"):
        out = crf_refine(warped, rgb, fg, CRFParams(backend=backend, theta_pos=0.25))
        assert out.dtype == np.uint16
        assert set(np.unique(out)) <= {0, 4, 11}
        assert (out == ids[gt]).mean() > 0.9
    # a part the warp lost can be assigned only when listed
    out = crf_refine(np.zeros_like(warped), rgb, fg, CRFParams(backend="fallback"), part_ids=np.array([4]))
    assert set(np.unique(out)) <= {0, 4}
    assert not crf_refine(np.zeros_like(warped), rgb, fg).any()
    with pytest.raises(ValueError):
        crf_refine(warped[:5], rgb, fg)


def test_backend_selection(monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.align import crf

    rgb, _, noisy = scene()
    probs = label_probabilities(noisy, rgb.min(axis=2) > 240, np.array([0, 1, 2]))
    fallback = dense_crf(probs, rgb, CRFParams(backend="fallback"))
    assert fallback.shape == probs.shape
    if pydensecrf_available():
        assert dense_crf(probs, rgb, CRFParams(backend="pydensecrf")).shape == probs.shape
    with pytest.raises(ValueError):
        dense_crf(probs, rgb, CRFParams(backend="nope"))  # type: ignore[arg-type]
    # without pydensecrf, "auto" runs the fallback
    monkeypatch.setattr(crf, "pydensecrf_available", lambda: False)
    assert np.array_equal(dense_crf(probs, rgb, CRFParams()), fallback)


def test_white_background_spares_near_white_parts_the_mask_missed() -> None:
    rgb = np.full((24, 24, 3), 255, np.uint8)
    rgb[4:20, 4:12] = (120, 60, 40)  # a dark part the mask has
    rgb[4:20, 12:20] = (225, 222, 215)  # a near-white part the mask missed
    rgb[..., :] = np.clip(rgb + np.random.default_rng(0).normal(0, 2, rgb.shape), 0, 255).astype(np.uint8)
    mask = np.zeros((24, 24), bool)
    mask[4:20, 4:12] = True
    warped = np.zeros((24, 24), np.uint16)
    warped[4:20, 4:12] = 1
    warped[4:20, 12:20] = 2
    white = white_pixels(rgb, 90.0)
    assert white[0, 0] and not white[10, 8] and not white[10, 15]
    kept = crf_refine(warped, rgb, mask, CRFParams(background="white", backend="fallback"))
    assert (kept[4:20, 12:20] == 2).mean() > 0.9
    assert not kept[0].any()
    wiped = crf_refine(warped, rgb, mask, CRFParams(background="mask", backend="fallback"))
    assert (wiped[4:20, 12:20] == 0).mean() > 0.9
