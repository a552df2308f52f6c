"""Running registered stages: whole (in-process, as `photoshape run` does) or one claimed unit at a time.

`run_all` runs stages in registry order, each resuming from what earlier runs recorded, and records
the resolved profile and every stage's report in `pipeline_run`. `plan_batches` + `process` are the
fan-out path the flows use: a unit's items are claimed in `work_claim` before the stage runs them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.db import claims
from photoshape_flow.pipeline.progress import StageProgress
from photoshape_flow.profiles import Profile, ResolvedProfile, resolve_profile
from photoshape_flow.stages.context import StageContext
from photoshape_flow.stages.registry import REGISTRY, get_stage
from photoshape_flow.stages.report import StageReport
from photoshape_flow.stages.work import WorkUnit, claim_hash

log = logging.getLogger(__name__)


def _resolved(profile: str | Profile | ResolvedProfile) -> ResolvedProfile:
    return profile if isinstance(profile, ResolvedProfile) else resolve_profile(profile)


def _timed(call: Callable[[], StageReport]) -> StageReport:
    """The report of `call` with its wall time: the one place a stage's seconds are measured."""
    start = time.perf_counter()
    report = call()
    report.seconds = time.perf_counter() - start
    return report


def run_stage(name: str, profile: str | Profile | ResolvedProfile, ctx: StageContext,
              work: Any = None) -> StageReport:
    """One stage with its section of the profile; `work` limits it to a unit (or an ingest request)."""
    stage = get_stage(name)
    resolved = _resolved(profile)
    log.info("stage %s (profile %s) starting", name, resolved.name)
    report = _timed(lambda: stage.run(ctx, stage.config(resolved.profile), work))
    log.info("stage %s finished in %.1f s: %d done, %d skipped, %d failed, %d rejected", name, report.seconds,
             report.done, report.skipped, report.failed, report.rejected)
    return report


def run_all(profile: str | Profile | ResolvedProfile, ctx: StageContext, names: Sequence[str] | None = None,
            ingest: Any = None, origin: str = "cli",
            on_stage: Callable[[StageReport], None] | None = None) -> list[StageReport]:
    """The stages in `names` (default: all) in registry order; the run and its profile are recorded."""
    resolved = _resolved(profile)
    wanted = [s.name for s in REGISTRY if names is None or s.name in names]
    run_id = start_run(ctx, resolved, wanted, origin)
    reports: list[StageReport] = []
    try:
        for name in wanted:
            reports.append(run_stage(name, resolved, ctx, ingest if name == "ingest" else None))
            record_report(ctx, run_id, reports[-1])
            if on_stage is not None:
                on_stage(reports[-1])
    except BaseException as exc:
        finish_run(ctx, run_id, f"{type(exc).__name__}: {exc}")
        raise
    finish_run(ctx, run_id, None)
    return reports


def start_run(ctx: StageContext, resolved: ResolvedProfile, stages: Sequence[str], origin: str) -> int:
    from photoshape_flow.db import models as m

    record = resolved.record()
    with ctx.session() as session:
        row = m.PipelineRun(origin=origin, profile_name=record["name"], overrides=record["overrides"],
                            profile=record["profile"], stages=list(stages), reports={}, status="running")
        session.add(row)
        session.flush()
        return int(row.id)


def record_report(ctx: StageContext, run_id: int, report: StageReport) -> None:
    from photoshape_flow.db import models as m

    with ctx.session() as session:
        row = session.get(m.PipelineRun, run_id)
        if row is not None:
            row.reports = {**(row.reports or {}), report.stage: report.to_dict()}


def finish_run(ctx: StageContext, run_id: int, error: str | None) -> None:
    from photoshape_flow.db import models as m
    from photoshape_flow.db.base import utcnow

    with ctx.session() as session:
        row = session.get(m.PipelineRun, run_id)
        if row is not None:
            row.status, row.error, row.finished_at = ("failed" if error else "ok"), error, utcnow()


# -- the fan-out path --------------------------------------------------------------------------------
def plan_batches(name: str, profile: str | Profile | ResolvedProfile, ctx: StageContext,
                 batch_size: int | None = None) -> list[WorkUnit]:
    """Units of at most `batch_size` items (the stage's default) over every part, in part order."""
    stage = get_stage(name)
    if stage.plan is None:
        raise ValueError(f"stage {name!r} does not fan out; run it whole")
    units = stage.plan(ctx, stage.config(_resolved(profile).profile))
    return [batch for unit in units for batch in unit.batches(batch_size or stage.batch_size)]


def process(name: str, unit: WorkUnit, profile: str | Profile | ResolvedProfile, ctx: StageContext) -> StageReport:
    """Claim `unit`'s items, run the stage on those this worker won, mark them done (or failed)."""
    stage = get_stage(name)
    cfg = stage.config(_resolved(profile).profile)
    if stage.claims_itself:
        return _timed(lambda: stage.run(ctx, cfg, unit))
    claim_stage = f"{name}:{unit.part}"
    digest = claim_hash(name, unit.part, cfg)
    with ctx.session() as session:
        won = claims.claim(session, claim_stage, [str(i) for i in unit.ids], params_hash=digest,
                           lease_seconds=ctx.settings.claim_lease_seconds, retry_failed=True)
    mine = tuple(int(k) for k in won)
    if not mine:
        return StageReport(name, skipped=len(unit.ids))
    try:
        report = _timed(lambda: stage.run(ctx, cfg, WorkUnit(unit.part, mine)))
    except Exception as exc:
        with ctx.session() as session:
            for key in won:
                claims.fail(session, claim_stage, key, f"{type(exc).__name__}: {exc}")
        raise
    with ctx.session() as session:
        claims.complete(session, claim_stage, won)
    report.skipped += len(unit.ids) - len(mine)
    return report


def finish(name: str, profile: str | Profile | ResolvedProfile, ctx: StageContext) -> StageReport | None:
    """The stage's step after all its units (pairs of coarse alignment, the gallery of publish)."""
    stage = get_stage(name)
    if stage.finish is None:
        return None
    finish_step = stage.finish
    return _timed(lambda: finish_step(ctx, stage.config(_resolved(profile).profile)))


def stage_progress(session: Session) -> list[StageProgress]:
    """Every stage's done / pending / failed counts, in pipeline order."""
    return [stage.progress(session) for stage in REGISTRY]


