"""The material-added re-run in this process: what `photoshape new-materials` runs.

The plan is `stages.new_materials.plan_material_rerun` (fit then publish of the affected pairs, no
retraining); the `new-materials` flow runs the same plan through the stage flows. Each stage goes
through the claims like any `photoshape run`; the fit report's details carry the changed-parts
counts (`fitting.changes`), recorded with the run in `pipeline_run`.
"""

from __future__ import annotations

from collections.abc import Callable

from photoshape_flow.fitting.changes import FitChanges, fit_changes, fit_snapshot
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.profiles import ResolvedProfile, resolve_profile
from photoshape_flow.stages.new_materials import MaterialRerun
from photoshape_flow.stages.registry import get_stage
from photoshape_flow.stages.run import finish, finish_run, plan_batches, process, record_report, run_stage, start_run

ORIGIN = "new-materials"  # `pipeline_run.origin` of a material-added re-run, CLI or flow


def run_limited(name: str, resolved: ResolvedProfile, ctx: StageContext, pairs: list[int]) -> StageReport:
    """One stage on just `pairs` of its planned items, then its finishing step (the gallery of publish)."""
    if not get_stage(name).fans_out:
        return run_stage(name, resolved, ctx)
    report = StageReport(name)
    for unit in plan_batches(name, resolved, ctx):
        mine = unit.only(pairs)
        if mine.ids:
            report = report.merge(process(name, mine, resolved, ctx))
    finished = finish(name, resolved, ctx)
    return report if finished is None else report.merge(finished)


def run_material_rerun(rerun: MaterialRerun, ctx: StageContext,
                       on_stage: Callable[[StageReport], None] | None = None) -> tuple[list[StageReport], FitChanges]:
    """Run `rerun`'s stages on its pairs, recorded as one `pipeline_run`; (reports, what fit changed)."""
    resolved = resolve_profile(rerun.profile, rerun.overrides)
    run_id = start_run(ctx, resolved, rerun.stages, ORIGIN)
    with ctx.session() as session:
        before = fit_snapshot(session, rerun.fit_key, rerun.pairs)
    changes, reports = FitChanges(), []
    try:
        for name in rerun.stages:
            report = run_limited(name, resolved, ctx, rerun.pairs)
            if name == "fit":
                with ctx.session() as session:
                    changes = fit_changes(before, fit_snapshot(session, rerun.fit_key, rerun.pairs), rerun.new_ids)
                report.details["changes"] = changes.as_dict()
            reports.append(report)
            record_report(ctx, run_id, report)
            if on_stage is not None:
                on_stage(report)
    except BaseException as exc:
        finish_run(ctx, run_id, f"{type(exc).__name__}: {exc}")
        raise
    finish_run(ctx, run_id, None)
    return reports, changes
