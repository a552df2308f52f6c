"""Coarse-alignment descriptors: square foreground crop, 100x100, Felzenszwalb HOG (section 4.1).

Renders and exemplars go through the same steps, so their descriptors are comparable:

1. grey image composited on white outside the foreground mask (renders: part IDs > 0; exemplars:
   the stored mask), because a product photo's background is white and the renderer's is too;
2. crop to the square bounding box of the foreground (centred; white where the square leaves the
   image), which removes focal length and translation from the problem (paper, section 4.1);
3. resize to `size` (area averaging when shrinking), optional Gaussian blur (paper: sigma 0.1,
   which is close to no blur at all), pad one HOG cell of white on each side so the silhouette's
   outer edge is seen, standardise to zero mean and unit variance (as the original code did);
4. HOG with `cell`-pixel cells, keeping a named channel set: 100 + 2x8 pixels give 13 x 13 cells,
   so "energy8" (the original's) is 1,352-D and "insensitive9" (the default, by measurement) 1,521-D.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from photoshape_flow.align.hog import channel_indices, hog_descriptor, hog_grid
from photoshape_flow.hashing import stable_hash
from photoshape_flow.imaging.squares import crop_square, square_box

DESCRIPTOR_CODE_VERSION = 1  # bump when the computation changes in a way the params do not show

# Chosen by bench/hog_channels.py on the medium demo (72 shapes, 200 exemplars; table in
# docs/benchmarks.md): the 9 contrast-insensitive orientations reach shape recall@1 0.85 (energy8,
# the original's choice: 0.67; all31: 0.87 at 3.4x the dimensions) for 1,521 dims.
DEFAULT_CHANNELS = "insensitive9"

# Default pair cut-off per channel set (squared L2): 1.5 x the largest top-1 distance of a correct
# match on the medium demo, rounded (the original's cut of 40 for energy8 was ~2x its demo maximum).
CALIBRATED_MAX_DISTANCE: dict[str, float] = {
    "insensitive9": 43.0,
    "energy8": 31.0,
    "all31": 108.0,
    "insensitive9+energy4": 55.0,
    "sensitive18+energy4": 62.0,
    "sensitive18+insensitive9": 95.0,
    "sensitive18": 52.0,
    "energy4": 10.0,
}


@dataclass(frozen=True)
class HogParams:
    """Everything that determines a coarse-alignment descriptor."""

    channels: str = DEFAULT_CHANNELS
    size: int = 100
    cell: int = 8
    pad: int = 8
    blur_sigma: float = 0.1
    standardize: bool = True
    render_size: int = 200  # sweep resolution before the crop (the original rendered 200x200)

    def __post_init__(self) -> None:
        channel_indices(self.channels)  # validates the name
        if self.size < 3 * self.cell:
            raise ValueError(f"descriptor size {self.size} is too small for {self.cell}-pixel cells")

    @property
    def name(self) -> str:
        """The `descriptor` column value: the family and channel set."""
        return f"hog-{self.channels}"

    @property
    def grid(self) -> tuple[int, int]:
        side = self.size + 2 * self.pad
        return hog_grid(side, side, self.cell)

    @property
    def dims(self) -> int:
        rows, cols = self.grid
        return rows * cols * len(channel_indices(self.channels))

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "code_version": DESCRIPTOR_CODE_VERSION}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> HogParams:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})

    def params_hash(self, **extra: Any) -> str:
        """sha256 of these parameters plus `extra` inputs (mesh ref, viewpoint set, ...)."""
        return stable_hash({"hog": self.to_dict(), **extra})


def to_grey(image: np.ndarray) -> np.ndarray:
    """Float grey image in 0..1 from uint8/uint16/float, grey or RGB(A) (Rec. 601 luma of the sRGB values)."""
    arr = np.asarray(image)
    if arr.dtype == np.uint8:
        arr = arr.astype(np.float32) / 255.0
    elif arr.dtype == np.uint16:
        arr = arr.astype(np.float32) / 65535.0
    else:
        arr = arr.astype(np.float32)
    if arr.ndim == 3:
        if arr.shape[2] == 1:
            arr = arr[..., 0]
        else:
            arr = arr[..., 0] * 0.299 + arr[..., 1] * 0.587 + arr[..., 2] * 0.114
    if arr.ndim != 2:
        raise ValueError(f"expected an (H, W) or (H, W, C) image, got shape {np.shape(image)}")
    return arr


def mask_from(mask: np.ndarray) -> np.ndarray:
    """Boolean foreground from a bool/uint8/uint16/float mask (any nonzero value; uint8 above 127)."""
    m = np.asarray(mask)
    if m.ndim == 3:
        m = m[..., 0]
    if m.dtype == np.bool_:
        return m
    if m.dtype == np.uint8:
        return m > 127
    return m > 0


def resize(image: np.ndarray, size: int) -> np.ndarray:
    """Square resize; area averaging when shrinking (anti-aliased), bilinear when growing."""
    import cv2

    if image.shape[0] == size and image.shape[1] == size:
        return image.astype(np.float32, copy=False)
    interp = cv2.INTER_AREA if image.shape[0] > size else cv2.INTER_LINEAR
    return cv2.resize(image.astype(np.float32, copy=False), (size, size), interpolation=interp)


def prepare(grey: np.ndarray, mask: np.ndarray, params: HogParams) -> np.ndarray:
    """Steps 1-3: the (size + 2 pad)^2 float32 image HOG is computed on (white = 1 background)."""
    fg = mask_from(mask)
    if fg.shape != grey.shape:
        raise ValueError(f"mask {fg.shape} and image {grey.shape} differ in size")
    box = square_box(fg)
    if box is None:
        side = params.size + 2 * params.pad
        return np.zeros((side, side), np.float32)  # nothing visible: a flat image, all-zero HOG
    composite = np.where(fg, grey, 1.0).astype(np.float32)
    small = resize(crop_square(composite, *box, fill=1.0), params.size)
    if params.blur_sigma > 0:
        from scipy.ndimage import gaussian_filter

        small = gaussian_filter(small, params.blur_sigma, mode="nearest", truncate=4.0)
    padded = np.pad(small, params.pad, mode="constant", constant_values=1.0)
    if params.standardize:
        padded = (padded - padded.mean()) / max(float(padded.std()), 1e-6)
    return padded.astype(np.float32)


def crop_mask(mask: np.ndarray, size: int) -> np.ndarray:
    """The foreground mask cropped like `prepare` crops the image, at `size` (for silhouette IoU)."""
    fg = mask_from(mask)
    box = square_box(fg)
    if box is None:
        return np.zeros((size, size), bool)
    return resize(crop_square(fg.astype(np.float32), *box, fill=0.0), size) >= 0.5


def descriptors(greys: np.ndarray, masks: np.ndarray, params: HogParams) -> np.ndarray:
    """Descriptors of a batch of grey images (N, H, W) with masks (N, H, W): (N, dims) float32."""
    prepared = np.stack([prepare(g, m, params) for g, m in zip(greys, masks, strict=True)])
    return hog_descriptor(prepared, params.channels, params.cell)


def view_descriptors(shaded: np.ndarray, part_ids: np.ndarray, params: HogParams) -> np.ndarray:
    """Descriptors of a viewpoint sweep (`SweepResult.shaded`, `SweepResult.part_ids`): (N, dims)."""
    return descriptors(np.asarray(shaded, np.float32), np.asarray(part_ids) > 0, params)


def exemplar_descriptor(image: np.ndarray, mask: np.ndarray, params: HogParams) -> np.ndarray:
    """Descriptor of an exemplar photo (RGB or grey, any dtype) with its foreground mask: (dims,)."""
    grey = to_grey(image)
    fg = mask_from(mask)
    if fg.shape != grey.shape:  # masks may be stored at another resolution than the crop
        import cv2

        fg = cv2.resize(fg.astype(np.uint8), grey.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    return descriptors(grey[None], fg[None], params)[0]


def render_view_descriptors(
    renderer: Any, shape: Any, cameras: Sequence[Any], params: HogParams, batch: int = 64
) -> np.ndarray:
    """Render the shaded sweep of `shape` (batches of `batch` views) and describe it: (N, dims) float32."""
    out = np.empty((len(cameras), params.dims), np.float32)
    for start in range(0, len(cameras), batch):
        sweep = renderer.sweep(shape, list(cameras[start : start + batch]), size=params.render_size, shaded=True)
        if sweep.shaded is None:
            raise RuntimeError("renderer returned no shaded images for the sweep")
        out[start : start + batch] = view_descriptors(sweep.shaded, sweep.part_ids, params)
    return out
