"""Exemplar cleaning of section 3.2: foreground by a pixel-value threshold, tight square crop, resize.

Product photos sit on near-white backgrounds, so the foreground is "darker than a threshold". The
original code thresholds at the 80th percentile of the image's unique grey levels; for photographs,
whose grey levels are dense, that is 80% of the way from the darkest to the brightest level, which
is what we compute (it also behaves on synthetic images with few distinct levels). Images whose
levels span less than `min_contrast` (blank or noise-only) have no foreground. Specks smaller
than a minimum area are dropped so JPEG noise cannot widen the crop. The crop is the square around
the foreground's bounding box, white where it leaves the photo, resized to `size` (never upscaled).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from photoshape_flow.imaging.io import BadImageError
from photoshape_flow.imaging.squares import crop_square, crop_square_resized

MAX_CROP_PIXELS = 64_000_000  # the native square is built only up to this; larger ones are resized as cut


@dataclass(frozen=True)
class ExemplarOptions:
    size: int = 512  # stored side; the paper used 1000
    level_fraction: float = 0.8  # threshold between darkest (0) and brightest (1) grey level
    min_speck_fraction: float = 0.0005  # components smaller than this share of the image are noise
    min_foreground_fraction: float = 0.002  # reject images with less foreground
    max_foreground_fraction: float = 0.95  # ... or more (the background is not white)
    min_foreground_side: int = 8  # reject foregrounds whose bounding box is smaller (pixels)
    min_background_level: float = 200.0  # median grey of the background must be at least this
    min_contrast: float = 32.0  # brightest minus darkest grey level; below it there is no object
    margin: float = 0.0  # extra border around the bounding box, as a fraction of its side

    def as_dict(self) -> dict[str, Any]:
        return {
            "size": self.size,
            "level_fraction": self.level_fraction,
            "min_speck_fraction": self.min_speck_fraction,
            "min_foreground_fraction": self.min_foreground_fraction,
            "max_foreground_fraction": self.max_foreground_fraction,
            "min_foreground_side": self.min_foreground_side,
            "min_background_level": self.min_background_level,
            "min_contrast": self.min_contrast,
            "margin": self.margin,
        }


@dataclass
class PreparedExemplar:
    image: np.ndarray  # (size, size, 3) uint8, the square crop
    mask: np.ndarray  # (size, size) uint8, 255 = foreground
    native_width: int
    native_height: int
    crop: dict[str, int]  # x0, y0, side in native pixels (x0/y0 may be negative: white padding)
    foreground_fraction: float  # of the stored crop
    meta: dict[str, Any] = field(default_factory=dict)


def grey_levels(rgb: np.ndarray) -> np.ndarray:
    """Luminance (ITU-R 601, as skimage.rgb2gray's weights are close to) in 0..255 float32."""
    rgb = np.asarray(rgb, np.float32)
    return rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114


def foreground_mask(rgb: np.ndarray, options: ExemplarOptions | None = None) -> tuple[np.ndarray, float]:
    """Boolean foreground mask and the threshold used."""
    import cv2

    options = options or ExemplarOptions()
    grey = grey_levels(rgb)
    lo = float(grey.min())
    hi = float(grey.max())
    threshold = lo + options.level_fraction * (hi - lo)
    mask = grey < threshold
    if hi - lo < options.min_contrast:  # flat or noise-only image: nothing stands out
        mask[:] = False
    if mask.any():
        count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
        min_area = max(4, int(options.min_speck_fraction * mask.size))
        keep = np.zeros(count, bool)
        keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
        if not keep.any() and count > 1:  # everything is small: keep the largest
            keep[1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))] = True
        mask = keep[labels]
    return mask, threshold


def prepare_exemplar(rgb: np.ndarray, options: ExemplarOptions | None = None,
                     max_crop_pixels: int = MAX_CROP_PIXELS) -> PreparedExemplar:
    """Mask, crop and resize a decoded photo; BadImageError when there is no usable foreground.

    The square around the foreground is cut at native resolution (then resized) only while it has
    at most `max_crop_pixels`; a larger one is cut and resized in one step (`crop_square_resized`),
    so the memory a crop takes is bounded by the photo and the stored size, never by side^2.
    """
    import cv2

    options = options or ExemplarOptions()
    h, w = rgb.shape[:2]
    mask, threshold = foreground_mask(rgb, options)
    fraction = float(mask.mean()) if mask.size else 0.0
    if fraction <= 0:
        raise BadImageError("no foreground (the image is blank or uniformly coloured)")
    if fraction < options.min_foreground_fraction:
        raise BadImageError(
            f"foreground too small ({fraction:.2%} of the image, minimum {options.min_foreground_fraction:.2%})"
        )
    if fraction > options.max_foreground_fraction:
        raise BadImageError(f"foreground fills {fraction:.0%} of the image (no white background)")
    background = grey_levels(rgb)[~mask]
    if background.size and float(np.median(background)) < options.min_background_level:
        raise BadImageError(
            f"background is not near-white (median grey {float(np.median(background)):.0f}, "
            f"minimum {options.min_background_level:.0f})"
        )
    ys, xs = np.nonzero(mask)
    bx0, bx1 = int(xs.min()), int(xs.max()) + 1
    by0, by1 = int(ys.min()), int(ys.max()) + 1
    if max(bx1 - bx0, by1 - by0) < options.min_foreground_side:
        raise BadImageError(f"foreground too small ({bx1 - bx0}x{by1 - by0} pixels)")
    side = max(bx1 - bx0, by1 - by0)
    side = int(round(side * (1.0 + 2.0 * options.margin)))
    x0 = int(np.floor((bx0 + bx1 - side) / 2.0))
    y0 = int(np.floor((by0 + by1 - side) / 2.0))
    out = min(options.size, side)
    if side * side > max_crop_pixels:
        crop = crop_square_resized(rgb, x0, y0, side, out, fill=255)
        crop_mask = crop_square_resized(mask.astype(np.uint8) * 255, x0, y0, side, out, fill=0)
        crop_mask = np.where(crop_mask >= 128, 255, 0).astype(np.uint8)
    else:
        crop = crop_square(rgb, x0, y0, side, fill=255)
        crop_mask = crop_square(mask.astype(np.uint8) * 255, x0, y0, side, fill=0)
    if crop.shape[0] != out:
        crop = cv2.resize(crop, (out, out), interpolation=cv2.INTER_AREA)
        crop_mask = cv2.resize(crop_mask, (out, out), interpolation=cv2.INTER_AREA)
        crop_mask = np.where(crop_mask >= 128, 255, 0).astype(np.uint8)
    return PreparedExemplar(
        image=np.ascontiguousarray(crop),
        mask=np.ascontiguousarray(crop_mask),
        native_width=w,
        native_height=h,
        crop={"x0": x0, "y0": y0, "side": side},
        foreground_fraction=float((crop_mask > 0).mean()),
        meta={"threshold": threshold, "bbox": [bx0, by0, bx1, by1], "native_foreground_fraction": fraction},
    )
