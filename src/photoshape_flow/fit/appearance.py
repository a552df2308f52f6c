"""Appearance statistics of one image region, and a distance between two regions that tolerates misalignment.

The rendered part and the photo's part never cover the same pixels exactly (fine alignment is off by
a few pixels, the shape is only a look-alike), so the distance compares distributions, not pixels:

- colour: the mean and the standard deviation of CIELAB over the region (the material's albedo
  under the estimated lighting, and its shading/texture contrast);
- texture: the mean and the standard deviation of the gradient magnitude of L* at two scales (full
  resolution and half), which separate smooth plastic or metal from wood grain or woven fabric;
- highlights: how far the bright tail of L* reaches above its median (90th and 99th percentiles minus
  the median), which separates glossy materials, whose few highlight pixels barely move the mean and
  the standard deviation, from matte ones of the same colour;
- deep texture (when the fit reads the frame with a backbone): the moments of ImageNet features over
  the region (`fit.deep_texture`), which tell patterns of one colour and contrast apart.

Each term is divided by a fixed scale (a just-noticeable CIELAB difference of about 10 for colour,
5 L* units per pixel for gradients) so the weights of `Weights` are comparable; the weights are
fitted on validation renders per classifier (`fit.calibrate`, docs/decisions.md D34), with the
profile's hand-set values (`FitConfig`, D32) as the fallback. Masks are eroded first so
boundary pixels, where the alignment error and anti-aliasing live, do not count.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from photoshape_flow.fit.deep_texture import DeepStats, deep_distance

LAB_SCALE = 10.0  # CIELAB units per unit of distance
GRADIENT_SCALE = 5.0  # L* per pixel per unit of distance
MIN_PIXELS = 12  # a region smaller than this has no statistics


@dataclass(frozen=True)
class Weights:
    """How much each statistic counts in `distance` (the `FitConfig` weights)."""

    color: float = 1.0  # CIELAB mean
    contrast: float = 0.5  # CIELAB standard deviation
    gradient: float = 0.5  # L* gradient-magnitude statistics, two scales
    highlight: float = 0.0  # L* upper percentiles above the median (counts once fitted: D38)
    deep: float = 0.0  # backbone feature moments (`fit.deep_texture`; counts once fitted: D54)


@dataclass(frozen=True)
class Appearance:
    """Statistics of one region: CIELAB mean and std (3 each), gradient mean/std at two scales (4), the
    L* 90th and 99th percentiles above the median (2); `deep`, the backbone's moments when measured."""

    lab_mean: np.ndarray
    lab_std: np.ndarray
    gradient: np.ndarray
    pixels: int
    highlight: np.ndarray = field(default_factory=lambda: np.zeros(2))
    deep: DeepStats | None = None


def srgb_float(rgb: np.ndarray) -> np.ndarray:
    """An sRGB image (uint8 or float 0..1) as float32 in 0..1."""
    rgb = np.asarray(rgb)[..., :3]
    if rgb.dtype == np.uint8:
        return rgb.astype(np.float32) / 255.0
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (L* 0..100, a*, b*) of an sRGB image (uint8 or float 0..1), D65."""
    return cv2.cvtColor(srgb_float(rgb), cv2.COLOR_RGB2LAB)


def erode(mask: np.ndarray, pixels: int) -> np.ndarray:
    """The mask shrunk by `pixels`; the unshrunk mask when nothing would be left."""
    mask = np.asarray(mask, bool)
    if pixels <= 0 or not mask.any():
        return mask
    kernel = np.ones((2 * pixels + 1, 2 * pixels + 1), np.uint8)
    eroded = cv2.erode(mask.astype(np.uint8), kernel) > 0
    return eroded if eroded.sum() >= MIN_PIXELS else mask


def soften(image: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian blur of `sigma` pixels (none when sigma <= 0).

    Applied to the photo and to every render alike (renders after they are blended with the photo's
    background, `fit.scene.FitScene.exposed_lab`) before any statistic: a product photo is softer
    than a path-traced render (lens, demosaicing, JPEG, a resize) and a low-spp render is noisier
    than a photo; both differences live at the finest scale, where they would swamp the texture
    statistics.
    """
    if sigma <= 0:
        return image
    return cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), sigmaX=float(sigma))


def _gradient_magnitude(lightness: np.ndarray) -> np.ndarray:
    gx = cv2.Sobel(lightness, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(lightness, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return np.sqrt(gx * gx + gy * gy)


@dataclass(frozen=True)
class Region:
    """A region's mask and the masks `appearance` derives from it alone: its gradient pixels at full
    and half resolution. A frame's part regions are the same for every candidate render and exposure
    the fit measures, so they are derived once (`Region.of`) and read for each."""

    mask: np.ndarray  # bool
    pixels: int
    fine: np.ndarray  # the mask shrunk by a pixel: where its full-resolution gradients are read
    coarse: np.ndarray | None  # the same at half resolution; None when the half-size mask is empty

    @classmethod
    def of(cls, mask: np.ndarray) -> Region:
        mask = np.asarray(mask, bool)
        height, width = mask.shape
        half = cv2.resize(mask.astype(np.uint8), (max(1, width // 2), max(1, height // 2)),
                          interpolation=cv2.INTER_NEAREST) > 0
        return cls(mask, int(mask.sum()), erode(mask, 1), erode(half, 1) if half.any() else None)


def appearance(lab: np.ndarray, mask: np.ndarray | Region) -> Appearance | None:
    """Statistics of the region `mask` of a CIELAB image (`to_lab`); None when it is too small."""
    region = mask if isinstance(mask, Region) else Region.of(mask)
    if region.pixels < MIN_PIXELS:
        return None
    mask = region.mask
    n = region.pixels
    pixels = lab[mask].astype(np.float64)
    lightness = np.ascontiguousarray(lab[..., 0], np.float32)
    # outside the region the gradient would see the background edge: fill it with the region's mean
    filled = np.where(mask, lightness, np.float32(pixels[:, 0].mean()))
    fine = _gradient_magnitude(filled)[region.fine]
    if region.coarse is None:
        coarse = fine
    else:
        half = cv2.resize(filled, (region.coarse.shape[1], region.coarse.shape[0]), interpolation=cv2.INTER_AREA)
        coarse = _gradient_magnitude(half)[region.coarse]
    coarse = coarse if coarse.size else fine
    gradient = np.array([fine.mean(), fine.std(), coarse.mean(), coarse.std()], np.float64)
    p50, p90, p99 = np.percentile(pixels[:, 0], [50.0, 90.0, 99.0])
    return Appearance(pixels.mean(axis=0), pixels.std(axis=0), gradient, n, np.array([p90 - p50, p99 - p50]))


def terms(a: Appearance, b: Appearance) -> np.ndarray:
    """The five unweighted distance terms (colour, contrast, gradient, highlight, deep), each over its scale.

    Kept apart so the weights can be fitted on validation renders (`fit.calibrate`). The deep term is
    0 unless both regions carry backbone statistics (a fit without a backbone, or the lighting search,
    which never measures it).
    """
    deep = deep_distance(a.deep, b.deep) if a.deep is not None and b.deep is not None else 0.0
    return np.array([float(np.linalg.norm(a.lab_mean - b.lab_mean)) / LAB_SCALE,
                     float(np.linalg.norm(a.lab_std - b.lab_std)) / LAB_SCALE,
                     float(np.linalg.norm(a.gradient - b.gradient)) / GRADIENT_SCALE,
                     float(np.linalg.norm(a.highlight - b.highlight)) / LAB_SCALE,
                     deep])


def weigh(values: np.ndarray, weights: Weights) -> float:
    """The weighted sum of `terms`."""
    color, contrast, gradient, highlight, deep = (float(v) for v in values)
    return (weights.color * color + weights.contrast * contrast + weights.gradient * gradient
            + weights.highlight * highlight + weights.deep * deep)


def distance(a: Appearance, b: Appearance, weights: Weights = Weights()) -> float:
    """Weighted distance between two regions' statistics (0: identical statistics)."""
    return weigh(terms(a, b), weights)
