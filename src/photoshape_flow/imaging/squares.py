"""Square boxes around a foreground and square crops: the framing shared by exemplars, renders and
descriptors (the paper crops both sides to "a square bounding box around their foreground masks")."""

from __future__ import annotations

import numpy as np


def square_box(mask: np.ndarray) -> tuple[int, int, int] | None:
    """(x0, y0, side) of the square centred on the foreground's bounding box; None when empty."""
    mask = np.asarray(mask, bool)
    ys = np.flatnonzero(mask.any(axis=1))
    xs = np.flatnonzero(mask.any(axis=0))
    if len(ys) == 0:
        return None
    y0, y1, x0, x1 = int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1
    side = max(y1 - y0, x1 - x0)
    return x0 - (side - (x1 - x0)) // 2, y0 - (side - (y1 - y0)) // 2, side


def crop_square_resized(image: np.ndarray, x0: int, y0: int, side: int, out: int,
                        fill: float | int = 0) -> np.ndarray:
    """`crop_square` resized to `out` x `out`, never allocating the `side` x `side` square.

    Only the part of the window inside the image is resized (by the same factor) and pasted onto an
    `out` x `out` canvas of `fill`, so memory follows the image and `out`, whatever `side` is: a strip
    whose foreground is 80000 pixels wide costs 80000 x 2 pixels, not 80000^2. INTER_AREA.
    """
    import cv2

    image = np.asarray(image)
    h, w = image.shape[:2]
    canvas = np.full((out, out, *image.shape[2:]), fill, dtype=image.dtype)
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + side, w), min(y0 + side, h)
    if sx1 <= sx0 or sy1 <= sy0:
        return canvas
    scale = out / side
    cx0, cy0 = min(int(round((sx0 - x0) * scale)), out - 1), min(int(round((sy0 - y0) * scale)), out - 1)
    cw = max(1, min(int(round((sx1 - sx0) * scale)), out - cx0))
    ch = max(1, min(int(round((sy1 - sy0) * scale)), out - cy0))
    region = cv2.resize(np.ascontiguousarray(image[sy0:sy1, sx0:sx1]), (cw, ch), interpolation=cv2.INTER_AREA)
    canvas[cy0 : cy0 + ch, cx0 : cx0 + cw] = region.reshape(ch, cw, *image.shape[2:])
    return canvas


def crop_square(image: np.ndarray, x0: int, y0: int, side: int, fill: float | int = 0) -> np.ndarray:
    """The `side` x `side` window at (x0, y0) of an (H, W[, C]) array, `fill` where it leaves the image."""
    image = np.asarray(image)
    h, w = image.shape[:2]
    out = np.full((side, side, *image.shape[2:]), fill, dtype=image.dtype)
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + side, w), min(y0 + side, h)
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = image[sy0:sy1, sx0:sx1]
    return out
