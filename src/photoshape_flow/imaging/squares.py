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
