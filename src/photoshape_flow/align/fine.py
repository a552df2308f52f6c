"""Fine alignment of one shape-exemplar pair (section 4.2): p_coarse -> p_flow -> p_crf.

Pure arrays in, arrays out: the coarse part map (already cropped and scaled like the exemplar, see
`partmap`), the exemplar crop and its mask. The three maps and their silhouette IoU with the
exemplar mask are returned; `part_label_accuracy` scores a map against ground truth.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from photoshape_flow.align.crf import CRFParams, crf_refine
from photoshape_flow.align.flow import FlowParams, flow_warp
from photoshape_flow.align.partmap import exemplar_at, resize_labels

FINE_ALIGNMENT_VERSION = 1  # bump when the science changes results, to invalidate stored rows


@dataclass(frozen=True)
class FineParams:
    """Working resolution and the flow and CRF settings of the fine step.

    320^2 rather than the original's 500^2: the dense CRF costs ~2.5x more at 500^2 on CPU, and the
    demo's exemplars are stored at 144-320 pixels anyway.
    """

    size: int = 320
    flow: FlowParams = field(default_factory=FlowParams)
    crf: CRFParams = field(default_factory=CRFParams)

    def to_dict(self) -> dict[str, Any]:
        return {
            "version": FINE_ALIGNMENT_VERSION,
            "size": self.size,
            "flow": self.flow.to_dict(),
            "crf": self.crf.to_dict(),
        }

    def digest(self) -> str:
        """Stable hash of the settings (part of each Alignment row's params_hash)."""
        payload = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(payload.encode()).hexdigest()


@dataclass
class FineAlignment:
    """The part maps after each step (uint16, 0 = background) and their silhouette IoU."""

    coarse: np.ndarray
    flow: np.ndarray
    crf: np.ndarray
    iou_coarse: float
    iou_flow: float
    iou_crf: float
    flow_field: np.ndarray | None = None  # (H, W, 2) exemplar pixel -> coarse-map offset


def silhouette_iou(labels: np.ndarray, mask: np.ndarray) -> float:
    """IoU of a part map's foreground (label > 0) with a mask; 1.0 when both are empty."""
    a = np.asarray(labels) > 0
    b = np.asarray(mask, bool)
    union = np.logical_or(a, b).sum()
    if union == 0:
        return 1.0
    return float(np.logical_and(a, b).sum() / union)


def part_label_accuracy(pred: np.ndarray, gt: np.ndarray) -> float:
    """Fraction of ground-truth foreground pixels (gt > 0) whose predicted part label is right."""
    pred = np.asarray(pred)
    gt = np.asarray(gt)
    if pred.shape != gt.shape:
        raise ValueError(f"shape mismatch: pred {pred.shape}, gt {gt.shape}")
    fg = gt > 0
    if not fg.any():
        return float("nan")
    return float((pred[fg] == gt[fg]).mean())


def align_pair(
    part_map_coarse: np.ndarray,
    exemplar_rgb: np.ndarray,
    exemplar_mask: np.ndarray,
    params: FineParams | None = None,
) -> FineAlignment:
    """Warp the coarse part map onto the exemplar silhouette, then clean it with the dense CRF.

    All outputs are at `params.size`; the coarse map and the exemplar are resized there (nearest
    for labels, area for the photo) when they are not already.
    """
    params = params or FineParams()
    size = params.size
    coarse = resize_labels(np.asarray(part_map_coarse).astype(np.uint16), size)
    rgb, fg = exemplar_at(exemplar_rgb, exemplar_mask, size)
    warped, flow = flow_warp(coarse, fg, params.flow)
    part_ids = np.unique(coarse)
    cleaned = crf_refine(warped, rgb, fg, params.crf, part_ids=part_ids[part_ids > 0])
    return FineAlignment(
        coarse=coarse,
        flow=warped.astype(np.uint16),
        crf=cleaned,
        iou_coarse=silhouette_iou(coarse, fg),
        iou_flow=silhouette_iou(warped, fg),
        iou_crf=silhouette_iou(cleaned, fg),
        flow_field=flow,
    )
