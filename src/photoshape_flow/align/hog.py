"""Felzenszwalb HOG (Felzenszwalb et al. 2010, PAMI), written in numpy and vectorised over a batch.

This follows ``features.cc`` of the voc-release code (the one ``pyhog`` wraps) step by step:

1. Centred gradients per pixel; for colour images, the channel with the largest gradient wins.
2. The gradient angle snaps to one of 18 contrast-sensitive orientations (9 unit vectors and their
   negatives), and its magnitude is spread over the 4 nearest cells by bilinear interpolation.
3. Each cell is normalised by the energy of the 4 blocks of 2x2 cells that contain it; every
   normalised value is truncated at 0.2.
4. Per cell: 18 contrast-sensitive orientations (sum of the 4 normalisations, x 0.5), 9
   contrast-insensitive ones (opposite orientations summed), and 4 texture/energy features (the
   sum of the truncated sensitive values under each normalisation, x 0.2357).

Channels 0-17 are sensitive, 18-26 insensitive, 27-30 energy. The output has (round(H/cell) - 2) x
(round(W/cell) - 2) cells, so a 100x100 image padded by one cell on each side gives 13 x 13 x 31.
`CHANNEL_SETS` names the channel choices compared in ``bench/hog_channels.py``; "energy8" is what the
original PhotoShape code kept (the last 8 channels: insensitive orientations 5-8 and the 4 energies).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

NUM_CHANNELS = 31
TRUNCATION = 0.2
EPS = 1e-4
_CHUNK = 16  # images per internal batch: small enough for the per-pixel passes to stay in cache

# features.cc's unit vectors (to 4 decimals, as there) for the 9 orientations in [0, pi)
_UU = np.array([1.0000, 0.9397, 0.7660, 0.500, 0.1736, -0.1736, -0.5000, -0.7660, -0.9397])
_VV = np.array([0.0000, 0.3420, 0.6428, 0.8660, 0.9848, 0.9848, 0.8660, 0.6428, 0.3420])

SENSITIVE = tuple(range(0, 18))
INSENSITIVE = tuple(range(18, 27))
ENERGY = tuple(range(27, 31))

CHANNEL_SETS: dict[str, tuple[int, ...]] = {
    "all31": tuple(range(NUM_CHANNELS)),
    "energy8": tuple(range(23, 31)),  # the original code's [:, :, -8:]
    "insensitive9+energy4": INSENSITIVE + ENERGY,
    "sensitive18+energy4": SENSITIVE + ENERGY,
    "sensitive18+insensitive9": SENSITIVE + INSENSITIVE,
    "insensitive9": INSENSITIVE,
    "sensitive18": SENSITIVE,
    "energy4": ENERGY,
}


def channel_indices(channels: str) -> tuple[int, ...]:
    """The channel indices of a named channel set."""
    try:
        return CHANNEL_SETS[channels]
    except KeyError:
        raise ValueError(f"unknown HOG channel set {channels!r}; known: {sorted(CHANNEL_SETS)}") from None


def _round_half_up(x: float) -> int:
    return int(np.floor(x + 0.5))


def hog_grid(height: int, width: int, cell: int = 8) -> tuple[int, int]:
    """(rows, cols) of output cells for an image of the given size."""
    return max(_round_half_up(height / cell) - 2, 0), max(_round_half_up(width / cell) - 2, 0)


@lru_cache(maxsize=16)
def _binning(height: int, width: int, cell: int):  # type: ignore[no-untyped-def]
    """Per-pixel sample positions and bilinear cell weights; a pure function of the image size."""
    by, bx = _round_half_up(height / cell), _round_half_up(width / cell)
    ys = np.arange(1, by * cell - 1)
    xs = np.arange(1, bx * cell - 1)
    sy = np.minimum(ys, height - 2)  # features.cc samples the last valid pixel beyond the image
    sx = np.minimum(xs, width - 2)

    def axis(coords: np.ndarray, blocks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        p = (coords + 0.5) / cell - 0.5
        i0 = np.floor(p).astype(np.int64)
        w1 = p - i0  # weight of cell i0 + 1
        w0 = 1.0 - w1
        ok0 = i0 >= 0
        ok1 = i0 + 1 < blocks
        return i0, np.where(ok0, w0, 0.0), np.where(ok1, w1, 0.0), np.clip(i0, 0, blocks - 1)

    iy, wy0, wy1, iy0c = axis(ys, by)
    ix, wx0, wx1, ix0c = axis(xs, bx)
    iy1c = np.clip(iy + 1, 0, by - 1)
    ix1c = np.clip(ix + 1, 0, bx - 1)
    # four (cell index, weight) pairs per pixel, as (Hv, Wv) grids
    cells = []
    for cy, wy in ((iy0c, wy0), (iy1c, wy1)):
        for cx, wx in ((ix0c, wx0), (ix1c, wx1)):
            cells.append(((cy[:, None] * bx + cx[None, :]).ravel(), (wy[:, None] * wx[None, :]).ravel()))
    return by, bx, sy, sx, cells


def hog(images: np.ndarray, cell: int = 8) -> np.ndarray:
    """Felzenszwalb HOG of one grey image (H, W), a grey batch (N, H, W) or a colour batch (N, H, W, C).

    Returns (rows, cols, 31) for one image, else (N, rows, cols, 31), float32.

    Images are float (any scale: the block normalisation makes the result invariant to a global
    gain up to `EPS`). Colour images take the channel with the strongest gradient per pixel.
    """
    arr = np.asarray(images, np.float32)
    single = False
    if arr.ndim == 2:
        arr, single = arr[None, :, :, None], True
    elif arr.ndim == 3:
        arr = arr[..., None]
    elif arr.ndim == 4:
        arr = arr[..., :3]
    else:
        raise ValueError(f"hog expects (H, W), (N, H, W) or (N, H, W, C) images, got shape {arr.shape}")
    n, height, width, _ = arr.shape
    if height < 3 * cell or width < 3 * cell:
        raise ValueError(f"image of {height}x{width} is too small for HOG with {cell}-pixel cells")
    rows, cols = hog_grid(height, width, cell)
    out = np.empty((n, rows, cols, NUM_CHANNELS), np.float32)
    for start in range(0, n, _CHUNK):
        out[start : start + _CHUNK] = _hog_chunk(arr[start : start + _CHUNK], cell)
    return out[0] if single else out


def _hog_chunk(arr: np.ndarray, cell: int) -> np.ndarray:
    """HOG of a (n, H, W, C) float32 batch; see the module docstring for the steps."""
    n, height, width, _ = arr.shape
    by, bx, sy, sx, cells = _binning(height, width, cell)

    # 1. gradients at the (clamped) sample positions, best colour channel per pixel
    rows = arr[:, sy]  # (n, Hv, W, C)
    dy = arr[:, sy + 1][:, :, sx] - arr[:, sy - 1][:, :, sx]
    dx = rows[:, :, sx + 1] - rows[:, :, sx - 1]
    mag2 = dx * dx + dy * dy
    if mag2.shape[-1] > 1:
        pick = np.argmax(mag2, axis=-1)[..., None]
        dx = np.take_along_axis(dx, pick, -1)
        dy = np.take_along_axis(dy, pick, -1)
        mag2 = np.take_along_axis(mag2, pick, -1)
    dx, dy, mag = dx[..., 0], dy[..., 0], np.sqrt(mag2[..., 0])  # (n, Hv, Wv)

    # 2. snap to 18 orientations
    # (a running strict maximum over the 9 axes, as in features.cc: the first of equal dots wins)
    best = np.zeros_like(dx)
    o = np.zeros(dx.shape, np.int64)
    dot, tmp, size = np.empty_like(dx), np.empty_like(dx), np.empty_like(dx)
    better, negative = np.empty(dx.shape, bool), np.empty(dx.shape, bool)
    for k in range(9):
        np.multiply(dx, np.float32(_UU[k]), out=dot)
        np.multiply(dy, np.float32(_VV[k]), out=tmp)
        dot += tmp
        np.abs(dot, out=size)
        np.greater(size, best, out=better)
        np.maximum(size, best, out=best)
        np.copyto(o, k, where=better)
        np.less(dot, 0, out=negative)
        negative &= better
        np.copyto(o, k + 9, where=negative)
    o = o.reshape(n, -1)
    mag = mag.reshape(n, -1)

    # bilinear votes into (n, by, bx, 18) histograms
    ncell = by * bx
    base = (np.arange(n, dtype=np.int64) * ncell)[:, None]
    hist = np.zeros(n * ncell * 18, np.float64)
    for cidx, w in cells:
        index = ((base + cidx[None, :]) * 18 + o).ravel()
        hist += np.bincount(index, weights=(mag * w[None, :]).ravel(), minlength=hist.size)
    hist = hist.reshape(n, by, bx, 18)

    # 3. block energies and the four normalisations of each interior cell
    sensitive = hist[..., :9] + hist[..., 9:]
    energy = np.sum(sensitive * sensitive, axis=-1)  # (n, by, bx)
    block = energy[:, :-1, :-1] + energy[:, 1:, :-1] + energy[:, :-1, 1:] + energy[:, 1:, 1:]
    inv = 1.0 / np.sqrt(block + EPS)  # (n, by-1, bx-1)
    oy, ox = by - 2, bx - 2
    norms = np.stack(
        [inv[:, 1 : oy + 1, 1 : ox + 1], inv[:, :oy, 1 : ox + 1], inv[:, 1 : oy + 1, :ox], inv[:, :oy, :ox]],
        axis=-1,
    )  # (n, oy, ox, 4): n1..n4 of features.cc
    h = hist[:, 1 : oy + 1, 1 : ox + 1]  # (n, oy, ox, 18)
    hs = np.minimum(h[..., :, None] * norms[..., None, :], TRUNCATION)  # (n, oy, ox, 18, 4)
    hi = np.minimum((h[..., :9] + h[..., 9:])[..., :, None] * norms[..., None, :], TRUNCATION)

    # 4. assemble the 31 channels
    out = np.empty((n, oy, ox, NUM_CHANNELS), np.float32)
    out[..., :18] = 0.5 * hs.sum(-1)
    out[..., 18:27] = 0.5 * hi.sum(-1)
    out[..., 27:31] = 0.2357 * hs.sum(-2)
    return out


def hog_descriptor(images: np.ndarray, channels: str = "energy8", cell: int = 8) -> np.ndarray:
    """HOG flattened to vectors, keeping the named channel set: (N, rows*cols*len(channels)) float32."""
    feats = hog(images, cell=cell)
    keep = list(channel_indices(channels))
    if feats.ndim == 3:
        feats = feats[None]
    return np.ascontiguousarray(feats[..., keep].reshape(feats.shape[0], -1))
