"""`CoarseConfig`: the parameters of the coarse alignment stage.

Its fields feed the params hashes stored on `ViewFeature`, `ExemplarMatch` and `Pair` rows, so the
fields and their defaults are part of the stored data's meaning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

from photoshape_flow.align.descriptors import CALIBRATED_MAX_DISTANCE, HogParams
from photoshape_flow.align.viewpoints import ViewpointParams


@dataclass(frozen=True)
class CoarseConfig:
    """Parameters of the coarse alignment stage."""

    viewpoint_set: str = "paper-456"
    viewpoint_version: int = 1
    viewpoint_params: ViewpointParams | None = None  # None: the named set's parameters
    hog: HogParams = field(default_factory=HogParams)
    exemplar_topk: int = 8  # shapes per exemplar in the reverse index (the original kept 8)
    shape_topn: int = 12  # exemplars per shape (paper, section 6: top 12)
    # drop pairs farther than this (squared L2); None: the channel set's calibrated cut-off
    # (descriptors.CALIBRATED_MAX_DISTANCE), or keep all if it has none; math.inf keeps all
    max_distance: float | None = None
    mode: str = "exact"  # or "bf16" (see align.retrieval)
    chunk_rows: int = 16384
    query_batch: int = 2048
    category: str | None = None  # restrict shapes and exemplars to one category

    def with_hog(self, **changes: Any) -> CoarseConfig:
        return replace(self, hog=replace(self.hog, **changes))

    @property
    def distance_cutoff(self) -> float | None:
        if self.max_distance is not None:
            return None if math.isinf(self.max_distance) else float(self.max_distance)
        return CALIBRATED_MAX_DISTANCE.get(self.hog.channels)
