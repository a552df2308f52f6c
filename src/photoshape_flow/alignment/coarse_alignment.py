"""Coarse alignment stage (section 4.1): viewpoint sets, descriptors, the reverse index, pairs.

Three steps, each idempotent and incremental (the pieces live in `alignment.coarse`):

1. `compute_view_features`: per shape, render the shaded viewpoint sweep and store one float16
   (views x dims) shard as a `ViewFeature` row; skipped when a row with the same params_hash exists.
2. `compute_exemplar_features`: per exemplar, the same descriptor from the stored crop and mask.
3. `compute_pairs`: the reverse index (per exemplar: the top-k shapes, best view each) by exact
   search, persisted as `ExemplarMatch` rows and inverted into per-shape lists of the top-N
   exemplars, written as `Pair` rows. A later run searches only what is new against what it has
   not seen, and rewrites only the pairs of the shapes whose exemplar lists changed.

`evaluate_coarse_alignment` scores the reverse index against the demo's ground truth.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from photoshape_flow.alignment.coarse.config import CoarseConfig
from photoshape_flow.alignment.coarse.evaluation import evaluate_coarse_alignment
from photoshape_flow.alignment.coarse.features import compute_exemplar_features, compute_view_features
from photoshape_flow.alignment.coarse.pairs import compute_pairs
from photoshape_flow.alignment.coarse.reverse_index import load_reverse_index
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.render.protocol import RendererProtocol

log = logging.getLogger(__name__)

STAGE = "coarse-alignment"


def run_coarse_alignment(
    settings: Settings | None = None,
    batch: int | None = None,
    *,
    config: CoarseConfig | None = None,
    renderer: RendererProtocol | None = None,
) -> dict[str, Any]:
    """Features of up to `batch` pending shapes and exemplars (all when None), then the pairs."""
    config = config or CoarseConfig()
    settings = settings or get_settings()
    start = time.perf_counter()
    summary = {
        "view_features": compute_view_features(config=config, settings=settings, renderer=renderer, limit=batch),
        "exemplar_features": compute_exemplar_features(config=config, settings=settings, limit=batch),
        "pairs": compute_pairs(config=config, settings=settings),
    }
    summary["seconds"] = round(time.perf_counter() - start, 3)
    log.info("coarse alignment: %s", summary)
    return summary


__all__ = [
    "STAGE",
    "CoarseConfig",
    "compute_exemplar_features",
    "compute_pairs",
    "compute_view_features",
    "evaluate_coarse_alignment",
    "load_reverse_index",
    "run_coarse_alignment",
]
