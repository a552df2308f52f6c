"""A validation render seen the way the fit stage sees a product photo: framed, and its part map misaligned.

The fit weights are fitted on validation renders (`fitting.calibration`), whose true material
per part is known; but the stage never sees a perfect part map. Fine alignment is off by a few pixels
(a shift, a slightly wrong scale, a boundary too far in or out), so the render's exact part map is
misaligned deterministically before it is used, or the weights would learn to trust pixel detail
(gradients at part boundaries) that real pairs do not have. The photographic degradation itself
(exposure, white balance, blur, noise, JPEG) is the demo's (`demo.exemplars.degrade`), applied by
the pipeline adapter, at the size the exemplars were stored at (`resampled`): degraded at the
render's own, smaller size, a photo's blur and JPEG blocks would cover ~3x more of the part than an
exemplar's do (docs/decisions.md D45).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from photoshape_flow.align.partmap import resize_labels
from photoshape_flow.imaging.squares import crop_square, square_box

REFERENCE_SIZE = 128  # the shift below is in pixels at this frame size, scaled with the frame
MAX_SHIFT = 2.0
MAX_SCALE = 0.03


@dataclass(frozen=True)
class Misalignment:
    """How an aligned part map errs: a shift (pixels), a scale about the centre, a boundary move."""

    dx: int
    dy: int
    scale: float
    boundary: int  # -1: part boundaries eroded, +1: the silhouette dilated, 0: neither


def sample_misalignment(rng: np.random.Generator, size: int) -> Misalignment:
    """A small alignment error for a frame of `size` pixels (shifts scale with the frame)."""
    reach = max(1, int(round(MAX_SHIFT * size / REFERENCE_SIZE)))
    dx, dy = (int(v) for v in rng.integers(-reach, reach + 1, 2))
    return Misalignment(dx, dy, float(rng.uniform(1.0 - MAX_SCALE, 1.0 + MAX_SCALE)), int(rng.integers(-1, 2)))


def resampled(hdr: np.ndarray, part_ids: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The render (bilinear) and its part ids (nearest) resampled to `size` pixels on their longer side."""
    part_ids = np.asarray(part_ids)
    scale = size / max(part_ids.shape)
    shape = (round(part_ids.shape[1] * scale), round(part_ids.shape[0] * scale))  # (width, height)
    return (cv2.resize(np.asarray(hdr, np.float32), shape, interpolation=cv2.INTER_LINEAR),
            cv2.resize(part_ids, shape, interpolation=cv2.INTER_NEAREST))


def misalign(labels: np.ndarray, error: Misalignment) -> np.ndarray:
    """`labels` (part index per pixel, 0 background) moved by `error`; nearest-neighbour, same shape."""
    labels = np.asarray(labels)
    h, w = labels.shape
    s = error.scale
    matrix = np.array([[s, 0.0, (1 - s) * (w - 1) / 2 + error.dx], [0.0, s, (1 - s) * (h - 1) / 2 + error.dy]])
    out = cv2.warpAffine(labels.astype(np.float32), matrix, (w, h), flags=cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(labels.dtype)
    kernel = np.ones((3, 3), np.uint8)
    if error.boundary < 0:  # every part shrinks: pixels next to another label are dropped
        f = out.astype(np.float32)
        edge = (cv2.dilate(f, kernel) != f) | (cv2.erode(f, kernel) != f)
        out = np.where(edge, 0, out).astype(labels.dtype)
    elif error.boundary > 0:  # the silhouette grows into the background
        grown = cv2.dilate(out.astype(np.float32), kernel).astype(labels.dtype)
        out = np.where(out > 0, out, grown)
    return out


def frame(image: np.ndarray, part_ids: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(image, part ids, foreground) cropped to the silhouette's square at `size` pixels.

    The square the exemplar crop and `fit.scene.FrameRenderer` use, so the render's frame and the fit
    stage's frame coincide; the image by area, the labels by nearest neighbour.
    """
    box = square_box(np.asarray(part_ids) > 0)
    if box is None:
        raise ValueError("nothing rendered: no part in the part map")
    fill = 255 if image.dtype == np.uint8 else 1.0
    crop = crop_square(image, *box, fill=fill)
    interp = cv2.INTER_AREA if crop.shape[0] > size else cv2.INTER_LINEAR
    rgb = cv2.resize(crop, (size, size), interpolation=interp)
    ids = resize_labels(crop_square(part_ids, *box, fill=0), size).astype(np.int32)
    return rgb, ids, ids > 0
