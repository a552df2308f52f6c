"""The coarse part map p_coarse (section 4.2): the shape's parts projected at the pair's camera.

Exemplars are stored as the tight square crop of their foreground (the square centred on the
foreground's bounding box, side = its longer side, contributing.md "Exemplars"); the part map is
cropped the same way and scaled to the working resolution with nearest-neighbour sampling, so the
two frames agree up to the alignment error that the flow and the CRF then correct.

To keep labels exact at the working resolution the render is zoomed onto the shape first: the
field of view is narrowed about the image centre (same camera centre and orientation, so the
projection is only scaled) until the projected vertices just fit, then rendered at
`oversample * size` pixels and cropped.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import cv2
import numpy as np

from photoshape_flow.imaging.squares import crop_square, square_box

__all__ = ["crop_square", "exemplar_at", "fit_part_map", "render_coarse_part_map", "resize_labels", "square_box",
           "zoom_to_fit"]


class PartIdRenderer(Protocol):
    def part_ids(self, shape: Any, camera: Any, size: int = 256) -> np.ndarray: ...


def resize_labels(labels: np.ndarray, size: int) -> np.ndarray:
    """Nearest-neighbour square resize of a label map (never invents a label)."""
    labels = np.asarray(labels)
    if labels.shape[:2] == (size, size):
        return labels.copy()
    return cv2.resize(labels, (size, size), interpolation=cv2.INTER_NEAREST)


def fit_part_map(part_ids: np.ndarray, size: int, target_box: tuple[int, int, int] | None = None) -> np.ndarray:
    """Crop a part-ID map to the square box of its foreground and scale it to `size` (uint16).

    `target_box` (x0, y0, side) in the `size` x `size` output is where that square lands (default:
    the whole frame, as for an exemplar cropped tightly); pass the square box of the exemplar's mask
    when the exemplar crop carries a margin.
    """
    ids = np.asarray(part_ids).astype(np.uint16)
    box = square_box(ids > 0)
    if box is None:
        raise ValueError("the part map is empty: the shape is not visible from this camera")
    if target_box is None or tuple(target_box) == (0, 0, size):
        return resize_labels(crop_square(ids, *box, fill=0), size)
    tx, ty, tside = (int(v) for v in target_box)
    if tside <= 0:
        raise ValueError(f"bad target box {target_box}")
    x0, y0, side = box
    scale = side / tside  # source pixels per output pixel
    outer = int(np.ceil(size * scale))
    src = crop_square(ids, int(round(x0 - tx * scale)), int(round(y0 - ty * scale)), outer, fill=0)
    return resize_labels(src, size)


def zoom_to_fit(shape: Any, camera: Any, margin: float = 0.02) -> Any:
    """The camera with its field of view narrowed (or widened) so the shape just fills the frame.

    Uses the projected vertices (they bound the rendered silhouette); the frame keeps its centre, so
    the image is the original projection scaled about the centre.
    """
    vertices = np.concatenate([np.asarray(p.vertices, np.float64) for p in shape.parts if len(p.vertices)])
    reference = 1000
    xy, depth = camera.project(vertices, reference)
    front = depth > 1e-6
    if not front.any():
        raise ValueError("the shape is behind the camera")
    half = reference / 2.0
    extent = float(np.abs(xy[front] - half).max()) / half
    zoom = max(extent * (1.0 + margin), 1e-3)
    fov = math.degrees(2.0 * math.atan(math.tan(math.radians(camera.fov) / 2.0) * zoom))
    return camera.replace(fov=min(fov, 170.0))


def render_coarse_part_map(
    renderer: PartIdRenderer,
    shape: Any,
    camera: Any,
    size: int = 500,
    oversample: float = 1.25,
    target_box: tuple[int, int, int] | None = None,
) -> np.ndarray:
    """p_coarse: exact part IDs at `camera`, square-cropped like the exemplar, `size`^2 uint16 (0 = background)."""
    zoomed = zoom_to_fit(shape, camera)
    render_size = int(math.ceil(size * oversample))
    return fit_part_map(renderer.part_ids(shape, zoomed, size=render_size), size, target_box)


def exemplar_at(rgb: np.ndarray, mask: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """The stored exemplar (square crop) at the working resolution: RGB uint8 (area) and bool mask."""
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=2)
    rgb = rgb[..., :3]
    if rgb.dtype != np.uint8:
        scale = 255.0 / 65535.0 if rgb.dtype == np.uint16 else 255.0
        rgb = np.clip(rgb.astype(np.float32) * scale, 0, 255).astype(np.uint8)
    m = np.asarray(mask)
    if m.ndim == 3:
        m = m[..., 0]
    if m.dtype == np.bool_:
        fg = m
    else:
        fg = m > (127 if m.dtype == np.uint8 else 0)
    if rgb.shape[:2] != (size, size):
        interp = cv2.INTER_AREA if rgb.shape[0] > size else cv2.INTER_LINEAR
        rgb = cv2.resize(rgb, (size, size), interpolation=interp)
    if fg.shape != (size, size):
        interp = cv2.INTER_AREA if fg.shape[0] > size else cv2.INTER_LINEAR
        fg = cv2.resize(fg.astype(np.float32), (size, size), interpolation=interp) >= 0.5
    return np.ascontiguousarray(rgb), fg
