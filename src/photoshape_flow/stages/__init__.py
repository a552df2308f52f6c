"""Pipeline stages: the registry (`REGISTRY`), their context and report types, and how they run.

    >>> import photoshape_flow.stages as s
    >>> [stage.name for stage in s.REGISTRY]  # doctest: +NORMALIZE_WHITESPACE
    ['ingest', 'coarse-alignment', 'fine-alignment', 'substances', 'training-renders', 'training',
     'inference', 'fit', 'publish']
"""

from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import Blocked, StageReport
from photoshape_flow.pipeline.runs import last_run_profile
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.stages.registry import REGISTRY, STAGE_NAMES, STAGES, Stage, get_stage
from photoshape_flow.stages.run import (
    finish,
    plan_batches,
    process,
    run_all,
    run_stage,
    stage_progress,
)

__all__ = [
    "REGISTRY", "STAGES", "STAGE_NAMES", "Blocked", "Stage", "StageContext", "StageReport", "WorkUnit",
    "finish", "get_stage", "last_run_profile", "plan_batches", "process", "run_all", "run_stage",
    "stage_progress",
]
