"""Dense CRF clean-up of the flow-warped part map (section 4.2, "Dense CRF").

The warped part map overlaps the exemplar but is noisy at its edges. As in the original code we
solve a fully connected CRF (Krahenbuhl and Koltun 2011) over the exemplar's pixels:

- unaries: softmax of the one-hot warped labels (logit `label_logit` on the warped label; the
  original used 1), logit `bg_logit` (3) on background where the exemplar is background (outside
  its mask and, by default, white), uniform where the warp left no part label;
- pairwise: an appearance kernel over position / (theta_pos * min(H, W)) and Lab colour / theta_lab
  with Potts weight `w_appearance` (the original's only kernel), plus an optional smoothness kernel
  over position alone (`w_smooth`, pixels `smooth_sxy`);
- mean-field inference for `iterations` steps.

Backends: pydensecrf2 (the reference permutohedral-lattice C++ code; `crf` extra) when importable,
else a mean field whose appearance message is a domain-transform filter (cv2.ximgproc.dtFilter, an
O(N) edge-aware approximation of the bilateral Gaussian) and whose smoothness message is a Gaussian
blur. `reference_meanfield` is the exact O(N^2) mean field, for tests on tiny images.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import cv2
import numpy as np

Backend = Literal["auto", "pydensecrf", "fallback"]


@dataclass(frozen=True)
class CRFParams:
    """Dense CRF settings: the original code's (`apply_segment_crf`) except where measured better.

    Measured on the demo "small" ground truth (bench/fine_alignment.py): with the original's weak
    unaries (label logit 1) and mask background the CRF merged same-material parts and erased
    near-white parts the ingest mask missed, lowering accuracy below the flow's; label logit 3 and
    white-only confident background make it an improvement.
    """

    theta_pos: float = 0.05  # appearance-kernel position std as a fraction of min(H, W)
    theta_lab: tuple[float, float, float] = (5.0, 5.0, 5.0)  # Lab std (L, a, b)
    w_appearance: float = 3.0  # Potts weight of the appearance kernel
    smooth_sxy: float = 3.0  # smoothness-kernel std in pixels
    w_smooth: float = 0.0  # Potts weight of the smoothness kernel (the original has none)
    iterations: int = 20
    bg_logit: float = 3.0  # logit of background where the exemplar is background
    label_logit: float = 3.0  # logit of the warped label (original 1: too weak, see bench)
    background: Literal["mask", "white"] = "white"  # confident background: outside the mask, or
    # outside the mask *and* white (the original: brighter than a percentile of the grey levels)
    white_percentile: float = 90.0  # of the unique min-channel levels (original 98)
    backend: Backend = "auto"
    fallback_color_scale: float = 3.0  # widens theta_lab for the domain-transform fallback (measured)

    def to_dict(self) -> dict[str, object]:
        data = asdict(self)
        data["theta_lab"] = list(self.theta_lab)
        return data


def white_pixels(rgb: np.ndarray, percentile: float = 90.0) -> np.ndarray:
    """Pixels brighter, in every channel, than `percentile` of the image's distinct min-channel levels.

    The original's background test (98th percentile); it leaves near-white object parts that an
    exemplar mask may have missed out of the confident background.
    """
    image = np.asarray(rgb)[..., :3]
    levels = np.unique(image.min(axis=2))
    threshold = np.percentile(levels, percentile)
    return (image > threshold).all(axis=2)


def pydensecrf_available() -> bool:
    try:
        import pydensecrf.densecrf  # noqa: F401
    except ImportError:
        return False
    return True


# -- unaries ------------------------------------------------------------------------------------


def softmax(logits: np.ndarray, axis: int = 0) -> np.ndarray:
    shifted = logits - logits.max(axis=axis, keepdims=True)
    e = np.exp(shifted)
    return e / e.sum(axis=axis, keepdims=True)


def label_probabilities(
    labels: np.ndarray,
    background: np.ndarray,
    label_ids: np.ndarray,
    bg_logit: float = 3.0,
    label_logit: float = 1.0,
) -> np.ndarray:
    """Unary probabilities (L, H, W) from a warped label map, as the original builds them.

    `label_ids[k]` is the part ID of CRF label k, `label_ids[0] == 0` (background). Logits are the
    one-hot labels (times `label_logit`); `background` pixels (exemplar background) get `bg_logit`
    on label 0; exemplar foreground the warp left unlabelled (label 0) is uniform.
    """
    label_ids = np.asarray(label_ids)
    if label_ids[0] != 0:
        raise ValueError("label_ids[0] must be 0 (background)")
    lookup = np.full(int(max(label_ids.max(), labels.max())) + 1, -1, np.int64)
    lookup[label_ids] = np.arange(len(label_ids))
    index = lookup[labels]
    if (index < 0).any():
        raise ValueError("labels holds part IDs missing from label_ids")
    n = len(label_ids)
    logits = (index[None] == np.arange(n)[:, None, None]).astype(np.float32) * np.float32(label_logit)
    logits[0][background] = bg_logit
    unlabelled = (~background) & (index == 0)
    logits[:, unlabelled] = 1.0 / n
    return softmax(logits, axis=0).astype(np.float32)


# -- features -----------------------------------------------------------------------------------


def rgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """sRGB (uint8 or float in 0..1) to CIE Lab float32 (L in 0..100)."""
    image = np.asarray(rgb)
    if image.dtype == np.uint8:
        image = image.astype(np.float32) / 255.0
    return cv2.cvtColor(np.ascontiguousarray(image[..., :3], dtype=np.float32), cv2.COLOR_RGB2Lab)


def appearance_features(lab: np.ndarray, theta_pos_px: float, theta_lab: tuple[float, float, float]) -> np.ndarray:
    """(5, H*W) float32: x, y / theta_pos_px and L, a, b / theta_lab (the kernel is exp(-|f|^2/2))."""
    h, w = lab.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    feats = [xx / theta_pos_px, yy / theta_pos_px] + [lab[..., c] / theta_lab[c] for c in range(3)]
    return np.ascontiguousarray(np.stack([f.reshape(-1) for f in feats]), dtype=np.float32)


def position_features(shape: tuple[int, int], sxy: float) -> np.ndarray:
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return np.ascontiguousarray(np.stack([xx.reshape(-1) / sxy, yy.reshape(-1) / sxy]), dtype=np.float32)


# -- inference ----------------------------------------------------------------------------------


def dense_crf(probs: np.ndarray, rgb: np.ndarray, params: CRFParams | None = None) -> np.ndarray:
    """Mean-field marginals (L, H, W) of the dense CRF with unaries -log(probs) on image `rgb`."""
    params = params or CRFParams()
    backend = params.backend
    if backend == "auto":
        backend = "pydensecrf" if pydensecrf_available() else "fallback"
    if backend == "pydensecrf":
        return pydensecrf_meanfield(probs, rgb, params)
    if backend == "fallback":
        return fallback_meanfield(probs, rgb, params)
    raise ValueError(f"unknown CRF backend {backend!r}")


def _theta_pos_px(shape: tuple[int, ...], params: CRFParams) -> float:
    return max(params.theta_pos * min(shape[0], shape[1]), 1e-3)


def pydensecrf_meanfield(probs: np.ndarray, rgb: np.ndarray, params: CRFParams) -> np.ndarray:
    """Krahenbuhl's permutohedral-lattice mean field through pydensecrf2."""
    import pydensecrf.densecrf as dcrf
    from pydensecrf.utils import unary_from_softmax

    n_labels, h, w = probs.shape
    crf = dcrf.DenseCRF(h * w, n_labels)
    crf.setUnaryEnergy(np.ascontiguousarray(unary_from_softmax(probs), dtype=np.float32))
    feats = appearance_features(rgb_to_lab(rgb), _theta_pos_px(probs.shape[1:], params), params.theta_lab)
    crf.addPairwiseEnergy(
        feats, compat=float(params.w_appearance), kernel=dcrf.DIAG_KERNEL, normalization=dcrf.NORMALIZE_SYMMETRIC
    )
    if params.w_smooth > 0:
        crf.addPairwiseEnergy(
            position_features((h, w), params.smooth_sxy),
            compat=float(params.w_smooth),
            kernel=dcrf.DIAG_KERNEL,
            normalization=dcrf.NORMALIZE_SYMMETRIC,
        )
    q = np.array(crf.inference(int(params.iterations)), dtype=np.float32)
    return q.reshape(n_labels, h, w)


def _edge_aware_mean(q: np.ndarray, guide: np.ndarray, sigma_spatial: float) -> np.ndarray:
    """Domain-transform filter of each label channel (dtFilter takes at most 4 channels at once)."""
    n_labels = q.shape[0]
    out = np.empty_like(q)
    for start in range(0, n_labels, 4):
        chunk = np.ascontiguousarray(np.moveaxis(q[start : start + 4], 0, -1))
        filtered = cv2.ximgproc.dtFilter(
            guide, chunk, float(sigma_spatial), 1.0, mode=cv2.ximgproc.DTF_NC, numIters=3
        )
        if filtered.ndim == 2:
            filtered = filtered[..., None]
        out[start : start + 4] = np.moveaxis(filtered, -1, 0)
    return out


def fallback_meanfield(probs: np.ndarray, rgb: np.ndarray, params: CRFParams) -> np.ndarray:
    """Mean field with fast filters when pydensecrf is absent.

    The appearance message is a domain-transform filter guided by Lab / (theta_lab *
    fallback_color_scale) with spatial std theta_pos * min(H, W); it is a normalised (averaging)
    filter like the symmetric normalisation of the reference code, so the Potts weights keep their
    meaning. Its edge stopping accumulates colour differences along paths, which makes it much
    stricter than the Gaussian over Lab, hence the wider colour scale (3x measured best, see
    bench/fine_alignment.py).
    """
    n_labels, h, w = probs.shape
    unary = -np.log(np.clip(probs, 1e-5, 1.0)).astype(np.float32)
    lab = rgb_to_lab(rgb)
    theta_lab = np.asarray(params.theta_lab, np.float32) * params.fallback_color_scale
    guide = np.ascontiguousarray(lab / theta_lab, dtype=np.float32)
    sigma_spatial = _theta_pos_px((h, w), params)
    q = softmax(-unary, axis=0)
    for _ in range(int(params.iterations)):
        logits = -unary + params.w_appearance * _edge_aware_mean(q, guide, sigma_spatial)
        if params.w_smooth > 0:
            blurred = np.stack([cv2.GaussianBlur(c, (0, 0), params.smooth_sxy) for c in q])
            logits += params.w_smooth * blurred
        q = softmax(logits, axis=0)
    return q.astype(np.float32)


def _gaussian_kernel(feats: np.ndarray) -> np.ndarray:
    sq = (feats**2).sum(axis=0)
    d2 = sq[:, None] + sq[None, :] - 2.0 * feats.T @ feats
    return np.exp(-0.5 * np.maximum(d2, 0.0))


def reference_meanfield(probs: np.ndarray, rgb: np.ndarray, params: CRFParams) -> np.ndarray:
    """Exact O(N^2) mean field with symmetric-normalised Gaussian kernels, for tiny images.

    Same update as the reference code: Q <- softmax(-U + sum_k w_k D^-1/2 K_k D^-1/2 Q), the kernel
    including i = j, which the permutohedral lattice only approximates.
    """
    n_labels, h, w = probs.shape
    unary = -np.log(np.clip(probs, 1e-5, 1.0)).reshape(n_labels, -1).astype(np.float64)
    kernels: list[tuple[float, np.ndarray]] = []
    feats = appearance_features(rgb_to_lab(rgb), _theta_pos_px((h, w), params), params.theta_lab).astype(np.float64)
    kernels.append((params.w_appearance, feats))
    if params.w_smooth > 0:
        kernels.append((params.w_smooth, position_features((h, w), params.smooth_sxy).astype(np.float64)))
    normalised = []
    for weight, f in kernels:
        k = _gaussian_kernel(f)
        norm = 1.0 / np.sqrt(k.sum(axis=1) + 1e-20)
        normalised.append((weight, norm[:, None] * k * norm[None, :]))
    q = softmax(-unary, axis=0)
    for _ in range(int(params.iterations)):
        logits = -unary.copy()
        for weight, k in normalised:
            logits += weight * (q @ k)
        q = softmax(logits, axis=0)
    return q.reshape(n_labels, h, w).astype(np.float32)


# -- the step -----------------------------------------------------------------------------------


def crf_refine(
    warped: np.ndarray,
    rgb: np.ndarray,
    foreground: np.ndarray,
    params: CRFParams | None = None,
    part_ids: np.ndarray | None = None,
) -> np.ndarray:
    """Clean a warped part map on the exemplar: returns part IDs (uint16, 0 = background).

    `part_ids` lists the parts the CRF may assign (default: those in `warped`); a part the warp
    lost entirely can come back only through the uniform unaries of unlabelled foreground.
    """
    params = params or CRFParams()
    warped = np.asarray(warped)
    foreground = np.asarray(foreground, bool)
    if warped.shape != foreground.shape or rgb.shape[:2] != warped.shape:
        raise ValueError(f"shape mismatch: warped {warped.shape}, rgb {rgb.shape}, mask {foreground.shape}")
    ids = np.unique(warped if part_ids is None else np.concatenate([np.ravel(part_ids), np.unique(warped)]))
    label_ids = np.concatenate([[0], ids[ids > 0]]).astype(np.int64)
    if len(label_ids) == 1:
        return np.zeros(warped.shape, np.uint16)
    background = ~foreground
    if params.background == "white":
        background &= white_pixels(rgb, params.white_percentile)
    probs = label_probabilities(warped, background, label_ids, params.bg_logit, params.label_logit)
    q = dense_crf(probs, rgb, params)
    return label_ids[q.argmax(axis=0)].astype(np.uint16)
