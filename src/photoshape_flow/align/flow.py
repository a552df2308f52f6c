"""Silhouette flow: warp the projected part map onto the exemplar (section 4.2, "SIFT Flow").

The original runs SIFT Flow (MATLAB) between the two *silhouettes*, each drawn as (1, 1, 1) on the
foreground and a (0, u, v) coordinate gradient on the background, so that the background anchors
the flow near the identity and the mask is not over-distorted. SIFT Flow is not available here;
this module offers candidates that keep that intent, compared by measurement (bench/fine_alignment.py):

- ``hs-coords``: a coarse-to-fine, multi-channel Horn-Schunck solver with warping, on the paper's
  three-channel (fg, u, v) encoding;
- ``hs-sdf``: the same solver on the signed distance to the silhouette edge (informative on both
  sides of the edge, so thin parts are pulled from afar) plus the (u, v) background channels;
- ``dis-sdf`` / ``deepflow-sdf``: OpenCV's DIS / DeepFlow, which take one 8-bit channel, on the
  8-bit signed distance;
- ``identity``: no flow (the coarse map), the baseline.

The flow is computed on the *exemplar* grid and points into the rendered map (backward warping),
at `scale` of the working resolution after padding and a slight blur as in the original, then
upsampled bicubically; labels are sampled with nearest-neighbour lookups, so no label is invented.

Measured choice (bench/fine_alignment.py at 320^2; table in docs/benchmarks.md):
mean part-label accuracy after flow + CRF over the synthetic 3-D pairs and the demo "small" ground
truth is 0.943 dis-sdf, 0.945 deepflow-sdf, 0.941 hs-sdf, 0.931 hs-coords; the first three tie
(within 0.005) and dis-sdf is 3-7x faster (deepflow-sdf also distorts the silhouettes of non-exact
pairs: demo IoU after flow 0.70 against 0.82), so dis-sdf is the default.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import cv2
import numpy as np

FlowMethod = Literal["identity", "hs-coords", "hs-sdf", "dis-sdf", "deepflow-sdf"]
FLOW_METHODS: tuple[str, ...] = ("identity", "hs-coords", "hs-sdf", "dis-sdf", "deepflow-sdf")


@dataclass(frozen=True)
class FlowParams:
    """Silhouette-flow settings (method and scale chosen by bench/fine_alignment.py)."""

    method: FlowMethod = "dis-sdf"
    scale: float = 1.0  # flow resolution / working resolution (the original halved 500^2; 0.5 measured worse)
    pad: float = 0.1  # padding on each side, fraction of the side (original: 50 px of 500)
    blur_sigma: float = 1.0  # Gaussian blur of the encodings, pixels at flow resolution
    sdf_range: float = 0.15  # signed distance clipped at this fraction of the side
    coord_weight: float = 1.0  # weight of the (u, v) background channels in the hs-* encodings
    alpha: float = 0.15  # smoothness weight of the hs-* solvers
    levels: int = 5  # pyramid levels of the hs-* solvers
    warps: int = 3  # re-linearisations per level
    iterations: int = 60  # Jacobi iterations per warp
    median: int = 5  # median filter of the flow after each warp (0 = none)

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


# -- encodings ----------------------------------------------------------------------------------


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """Euclidean distance to the silhouette edge, positive inside, negative outside (pixels)."""
    m = np.asarray(mask, bool).astype(np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, 5)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5)
    return (inside - outside).astype(np.float32)


def coordinate_encoding(mask: np.ndarray) -> np.ndarray:
    """The paper's silhouette image: (1, 1, 1) on the foreground, (0, u, v) on the background."""
    m = np.asarray(mask, bool)
    h, w = m.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    u /= max(w - 1, 1)
    v /= max(h - 1, 1)
    fg = m.astype(np.float32)
    return np.stack([fg, np.where(m, 1.0, u), np.where(m, 1.0, v)], axis=-1).astype(np.float32)


def sdf_encoding(mask: np.ndarray, range_px: float, coord_weight: float) -> np.ndarray:
    """Clipped signed distance in [-1, 1] plus the (u, v) background channels."""
    sdf = np.clip(signed_distance(mask) / max(range_px, 1.0), -1.0, 1.0)
    coords = coordinate_encoding(mask)[..., 1:] * coord_weight
    return np.concatenate([sdf[..., None], coords], axis=-1).astype(np.float32)


def sdf_uint8(mask: np.ndarray, range_px: float) -> np.ndarray:
    """The signed distance as one 8-bit channel (128 on the edge), for DIS and DeepFlow."""
    sdf = np.clip(signed_distance(mask) / max(range_px, 1.0), -1.0, 1.0)
    return np.round(128.0 + 127.0 * sdf).astype(np.uint8)


# -- the multi-channel solver -------------------------------------------------------------------

_AVERAGE = np.array([[1, 2, 1], [2, 0, 2], [1, 2, 1]], np.float32) / 12.0


def _channels(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 3 else image[..., None]


def _gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gx = np.empty_like(image)
    gy = np.empty_like(image)
    for c in range(image.shape[2]):
        gx[..., c] = cv2.Sobel(image[..., c], cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
        gy[..., c] = cv2.Sobel(image[..., c], cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / 8.0)
    return gx, gy


def _resize_channels(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    out = np.stack(
        [cv2.resize(image[..., c], size, interpolation=cv2.INTER_AREA) for c in range(image.shape[2])], axis=-1
    )
    return out.astype(np.float32)


def _remap(image: np.ndarray, flow: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    h, w = flow.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    map_x = xx + flow[..., 0]
    map_y = yy + flow[..., 1]
    return cv2.remap(image, map_x, map_y, interpolation, borderMode=cv2.BORDER_REPLICATE)


def horn_schunck_flow(
    target: np.ndarray,
    source: np.ndarray,
    alpha: float = 0.15,
    levels: int = 5,
    warps: int = 3,
    iterations: int = 60,
    median: int = 5,
    min_size: int = 12,
) -> np.ndarray:
    """Coarse-to-fine multi-channel Horn-Schunck with warping: target(x) ~ source(x + flow(x)).

    Images are (H, W) or (H, W, C) float32; the data term sums the linearised constancy of every
    channel, so any dense descriptor stack can be matched. Returns (H, W, 2) float32 (dx, dy).
    """
    target = _channels(np.asarray(target, np.float32))
    source = _channels(np.asarray(source, np.float32))
    if target.shape != source.shape:
        raise ValueError(f"shape mismatch: {target.shape} vs {source.shape}")
    if alpha <= 0:
        raise ValueError(f"alpha must be positive, got {alpha}")
    sizes = [(target.shape[1], target.shape[0])]
    while len(sizes) < levels and min(sizes[-1]) // 2 >= min_size:
        sizes.append(((sizes[-1][0] + 1) // 2, (sizes[-1][1] + 1) // 2))
    a2 = np.float32(alpha * alpha)
    flow: np.ndarray | None = None
    for size in reversed(sizes):
        t = target if size == sizes[0] else _resize_channels(target, size)
        s = source if size == sizes[0] else _resize_channels(source, size)
        if flow is None:
            flow = np.zeros((size[1], size[0], 2), np.float32)
        else:
            ratio_x = size[0] / flow.shape[1]
            ratio_y = size[1] / flow.shape[0]
            flow = cv2.resize(flow, size, interpolation=cv2.INTER_LINEAR)
            flow[..., 0] *= ratio_x
            flow[..., 1] *= ratio_y
        tgx, tgy = _gradients(t)
        for _ in range(warps):
            warped = _channels(_remap(s, flow))
            wgx, wgy = _gradients(warped)
            gx = 0.5 * (wgx + tgx)
            gy = 0.5 * (wgy + tgy)
            it = warped - t
            a = (gx * gx).sum(-1) + a2
            b = (gx * gy).sum(-1)
            c = (gy * gy).sum(-1) + a2
            bx = (gx * it).sum(-1)
            by = (gy * it).sum(-1)
            det = a * c - b * b
            total = flow.copy()
            for _ in range(iterations):
                avg = cv2.filter2D(total, -1, _AVERAGE, borderType=cv2.BORDER_REPLICATE)
                rx = -bx + a2 * (avg[..., 0] - flow[..., 0])
                ry = -by + a2 * (avg[..., 1] - flow[..., 1])
                total[..., 0] = flow[..., 0] + (c * rx - b * ry) / det
                total[..., 1] = flow[..., 1] + (a * ry - b * rx) / det
            flow = total
            if median:
                flow = np.stack([cv2.medianBlur(flow[..., k], median) for k in range(2)], axis=-1)
    assert flow is not None
    return flow


# -- the step -----------------------------------------------------------------------------------


def _dis_flow(target: np.ndarray, source: np.ndarray) -> np.ndarray:
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(0)
    return dis.calc(target, source, None)


def _deepflow(target: np.ndarray, source: np.ndarray) -> np.ndarray:
    return cv2.optflow.createOptFlow_DeepFlow().calc(target, source, None)


def silhouette_flow(source_mask: np.ndarray, target_mask: np.ndarray, params: FlowParams | None = None) -> np.ndarray:
    """Flow (H, W, 2) on the target (exemplar) grid into the source (render): T(x) ~ S(x + flow(x))."""
    params = params or FlowParams()
    source_mask = np.asarray(source_mask, bool)
    target_mask = np.asarray(target_mask, bool)
    if source_mask.shape != target_mask.shape:
        raise ValueError(f"shape mismatch: {source_mask.shape} vs {target_mask.shape}")
    h, w = target_mask.shape
    if params.method == "identity" or not source_mask.any() or not target_mask.any():
        return np.zeros((h, w, 2), np.float32)
    side = max(h, w)
    small = (max(int(round(w * params.scale)), 8), max(int(round(h * params.scale)), 8))
    pad = int(round(params.pad * max(small)))

    def prepare(mask: np.ndarray) -> np.ndarray:
        m = cv2.resize(mask.astype(np.uint8), small, interpolation=cv2.INTER_NEAREST)
        return np.pad(m, pad).astype(bool)

    src, tgt = prepare(source_mask), prepare(target_mask)
    range_px = params.sdf_range * side * small[0] / w
    blur = params.blur_sigma

    def smooth(image: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(image, (0, 0), blur) if blur > 0 else image

    if params.method == "hs-coords":
        enc_s, enc_t = (coordinate_encoding(m) for m in (src, tgt))
        if params.coord_weight != 1.0:
            enc_s[..., 1:] *= params.coord_weight
            enc_t[..., 1:] *= params.coord_weight
        flow = horn_schunck_flow(
            smooth(enc_t), smooth(enc_s), params.alpha, params.levels, params.warps, params.iterations, params.median
        )
    elif params.method == "hs-sdf":
        enc_s, enc_t = (sdf_encoding(m, range_px, params.coord_weight) for m in (src, tgt))
        flow = horn_schunck_flow(
            smooth(enc_t), smooth(enc_s), params.alpha, params.levels, params.warps, params.iterations, params.median
        )
    elif params.method in ("dis-sdf", "deepflow-sdf"):
        enc_s, enc_t = (smooth(sdf_uint8(m, range_px)) for m in (src, tgt))
        flow = (_dis_flow if params.method == "dis-sdf" else _deepflow)(enc_t, enc_s)
    else:
        raise ValueError(f"unknown flow method {params.method!r}")
    flow = flow[pad : pad + small[1], pad : pad + small[0]]
    full = cv2.resize(flow, (w, h), interpolation=cv2.INTER_CUBIC)
    full[..., 0] *= w / small[0]
    full[..., 1] *= h / small[1]
    return full.astype(np.float32)


def warp_labels(labels: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Backward-warp a label map with nearest-neighbour sampling (outside the map: 0)."""
    labels = np.asarray(labels)
    h, w = flow.shape[:2]
    if labels.shape != (h, w):
        raise ValueError(f"label map {labels.shape} does not match flow {flow.shape[:2]}")
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    map_x = xx + flow[..., 0]
    map_y = yy + flow[..., 1]
    if labels.size and (labels.min() < 0 or labels.max() > np.iinfo(np.uint16).max):
        raise ValueError("part labels must fit in uint16")
    src = labels.astype(np.uint16) if labels.dtype != np.uint16 else labels
    out = cv2.remap(src, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(labels.dtype)


def flow_warp(
    part_map: np.ndarray, target_mask: np.ndarray, params: FlowParams | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Warp a part map (0 = background) onto the target silhouette; returns (warped, flow)."""
    flow = silhouette_flow(np.asarray(part_map) > 0, target_mask, params)
    return warp_labels(part_map, flow), flow
