"""Stage `training-renders` (section 5.1): randomized renders conditioned on part substances.

It fans out over item positions (the round's train items, then its validation items): each unit
renders its positions, so workers on the work pool or Dask processes share the heaviest work of a
paper-scale run (156k renders) without rendering an item twice.
"""

from __future__ import annotations

from photoshape_flow.profiles import TrainingRendersConfig
from photoshape_flow.stages.context import StageContext
from photoshape_flow.stages.report import StageReport
from photoshape_flow.stages.work import WorkUnit

NAME = "training-renders"


def plan(ctx: StageContext, cfg: TrainingRendersConfig) -> list[WorkUnit]:
    return [WorkUnit("training", tuple(range(cfg.count)))]


def pool_versions(ctx: StageContext, round_: str, unit: WorkUnit) -> dict[int, str]:
    """Every item of a render unit (`round_`: training or bootstrap) carries the digest of the pools
    its spec is drawn from; the substances stage shares it for its bootstrap renders."""
    from photoshape_flow.pipeline.training_renders import pools_digest

    with ctx.session() as session:
        digest = pools_digest(session, round_)  # type: ignore[arg-type]
    return dict.fromkeys(unit.ids, digest)


def versions(ctx: StageContext, cfg: TrainingRendersConfig, unit: WorkUnit) -> dict[int, str]:
    return pool_versions(ctx, "training", unit)


def run(ctx: StageContext, cfg: TrainingRendersConfig, work: WorkUnit | None = None) -> StageReport:
    from photoshape_flow.pipeline.training_renders import run_training_renders

    summary = run_training_renders("training", cfg.count, cfg.size, cfg.spp, ctx.settings, renderer=ctx.renderer,
                                   indices=None if work is None else work.ids, progress=ctx.progress)
    return StageReport(
        NAME, done=int(summary["rendered"]), skipped=int(summary["skipped"]), failed=int(summary["failed"]),
        rejected=int(summary["rejected"]),
        details={"requested": summary["requested"], "splits": summary["splits"]},
    )
