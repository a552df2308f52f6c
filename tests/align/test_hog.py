"""Felzenszwalb HOG: against a loop-by-loop port of features.cc, shapes, invariances, channel sets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from photoshape_flow.align.hog import CHANNEL_SETS, NUM_CHANNELS, hog, hog_descriptor, hog_grid

UU = [1.0000, 0.9397, 0.7660, 0.500, 0.1736, -0.1736, -0.5000, -0.7660, -0.9397]
VV = [0.0000, 0.3420, 0.6428, 0.8660, 0.9848, 0.9848, 0.8660, 0.6428, 0.3420]


def reference_hog(im: np.ndarray, sbin: int) -> np.ndarray:
    """features.cc (voc-release), transcribed with scalar loops; im is (H, W, C) float64."""
    h_, w_, nch = im.shape
    by, bx = int(math.floor(h_ / sbin + 0.5)), int(math.floor(w_ / sbin + 0.5))
    hist = np.zeros((by, bx, 18))
    for x in range(1, bx * sbin - 1):
        for y in range(1, by * sbin - 1):
            sx, sy = min(x, w_ - 2), min(y, h_ - 2)
            best_v, dx, dy = -1.0, 0.0, 0.0
            for c in range(nch):
                ddy = im[sy + 1, sx, c] - im[sy - 1, sx, c]
                ddx = im[sy, sx + 1, c] - im[sy, sx - 1, c]
                v = ddx * ddx + ddy * ddy
                if v > best_v:
                    best_v, dx, dy = v, ddx, ddy
            best_dot, best_o = 0.0, 0
            for o in range(9):
                dot = UU[o] * dx + VV[o] * dy
                if dot > best_dot:
                    best_dot, best_o = dot, o
                elif -dot > best_dot:
                    best_dot, best_o = -dot, o + 9
            xp = (x + 0.5) / sbin - 0.5
            yp = (y + 0.5) / sbin - 0.5
            ixp, iyp = math.floor(xp), math.floor(yp)
            vx0, vy0 = xp - ixp, yp - iyp
            vx1, vy1 = 1 - vx0, 1 - vy0
            v = math.sqrt(best_v)
            if ixp >= 0 and iyp >= 0:
                hist[iyp, ixp, best_o] += vx1 * vy1 * v
            if ixp + 1 < bx and iyp >= 0:
                hist[iyp, ixp + 1, best_o] += vx0 * vy1 * v
            if ixp >= 0 and iyp + 1 < by:
                hist[iyp + 1, ixp, best_o] += vx1 * vy0 * v
            if ixp + 1 < bx and iyp + 1 < by:
                hist[iyp + 1, ixp + 1, best_o] += vx0 * vy0 * v
    norm = ((hist[..., :9] + hist[..., 9:]) ** 2).sum(-1)
    out = np.zeros((by - 2, bx - 2, 31))

    def blk(y: int, x: int) -> float:
        return 1.0 / math.sqrt(norm[y, x] + norm[y + 1, x] + norm[y, x + 1] + norm[y + 1, x + 1] + 1e-4)

    for y in range(by - 2):
        for x in range(bx - 2):
            n = [blk(y + 1, x + 1), blk(y, x + 1), blk(y + 1, x), blk(y, x)]
            src = hist[y + 1, x + 1]
            t = [0.0] * 4
            for o in range(18):
                hs = [min(src[o] * ni, 0.2) for ni in n]
                out[y, x, o] = 0.5 * sum(hs)
                t = [a + b for a, b in zip(t, hs, strict=True)]
            for o in range(9):
                s = src[o] + src[o + 9]
                out[y, x, 18 + o] = 0.5 * sum(min(s * ni, 0.2) for ni in n)
            out[y, x, 27:31] = [0.2357 * ti for ti in t]
    return out


def _blobs(rng: np.random.Generator, size: int) -> np.ndarray:
    """A smooth random image with edges in every direction."""
    yy, xx = np.mgrid[:size, :size] / size
    img = np.zeros((size, size))
    for _ in range(5):
        cy, cx, r = rng.uniform(0.2, 0.8, 3)
        img += (np.hypot(yy - cy, xx - cx) < r * 0.4) * rng.uniform(0.2, 1.0)
    return img + 0.05 * rng.standard_normal((size, size))


def test_matches_features_cc_grey_and_colour() -> None:
    rng = np.random.default_rng(0)
    grey = _blobs(rng, 44)  # 44/8 = 5.5 rounds up: also exercises the clamped samples beyond the image
    np.testing.assert_allclose(hog(grey, cell=8), reference_hog(grey[..., None], 8), atol=2e-5)
    colour = np.stack([_blobs(rng, 40), _blobs(rng, 40), _blobs(rng, 40)], axis=-1)
    np.testing.assert_allclose(hog(colour[None], cell=8)[0], reference_hog(colour, 8), atol=2e-5)


def test_shape_and_batch() -> None:
    rng = np.random.default_rng(1)
    batch = np.stack([_blobs(rng, 116) for _ in range(3)])
    feats = hog(batch)
    assert feats.shape == (3, 13, 13, NUM_CHANNELS) and feats.dtype == np.float32
    assert hog_grid(116, 116) == (13, 13)
    np.testing.assert_allclose(feats[1], hog(batch[1]), atol=1e-6)
    desc = hog_descriptor(batch, "energy8")
    assert desc.shape == (3, 1352)  # the paper's 13 x 13 x 8
    assert hog_descriptor(batch, "all31").shape == (3, 13 * 13 * 31)
    assert set(CHANNEL_SETS) >= {"energy8", "all31", "insensitive9+energy4"}
    with pytest.raises(ValueError, match="unknown HOG channel set"):
        hog_descriptor(batch, "nope")


def test_invariant_to_global_brightness_scale() -> None:
    img = _blobs(np.random.default_rng(2), 116)
    base = hog(img)
    assert base.max() > 0.1
    for gain in (0.5, 3.0):
        np.testing.assert_allclose(hog(img * gain), base, atol=2e-3)
    # a constant offset changes no gradient at all
    np.testing.assert_allclose(hog(img + 0.3), base, atol=1e-5)


def test_orientation_of_a_vertical_edge() -> None:
    img = np.zeros((48, 48))
    img[:, 24:] = 1.0  # brightness increases along +x: gradient angle 0 -> orientation 0
    feats = hog(img)
    strongest = feats[..., :18].sum(axis=(0, 1)).argmax()
    assert strongest == 0
    flipped = hog(1.0 - img)  # opposite contrast: the opposite sensitive bin, same insensitive bin
    assert flipped[..., :18].sum(axis=(0, 1)).argmax() == 9
    np.testing.assert_allclose(flipped[..., 18:], feats[..., 18:], atol=1e-6)
    assert np.all(feats <= 0.5 * 4 * 0.2 + 1e-6)  # four truncated normalisations, x 0.5
