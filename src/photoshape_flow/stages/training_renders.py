"""Stage `training-renders` (section 5.1): randomized renders conditioned on part substances."""

from __future__ import annotations

from photoshape_flow.profiles import TrainingRendersConfig
from photoshape_flow.stages.context import StageContext
from photoshape_flow.stages.report import StageReport

NAME = "training-renders"


def run(ctx: StageContext, cfg: TrainingRendersConfig, work: None = None) -> StageReport:
    from photoshape_flow.pipeline.training_renders import run_training_renders

    summary = run_training_renders("training", cfg.count, cfg.size, cfg.spp, ctx.settings, renderer=ctx.renderer)
    return StageReport(
        NAME, done=int(summary["rendered"]), skipped=int(summary["skipped"]), failed=int(summary["failed"]),
        rejected=int(summary["rejected"]),
        details={"requested": summary["requested"], "splits": summary["splits"]},
    )
