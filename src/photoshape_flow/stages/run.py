"""Running registered stages, always through the work claims, from the CLI and the flows alike.

`run_all` runs stages in registry order, each resuming from what earlier runs recorded, and records
the resolved profile and every stage's report in `pipeline_run`. `plan_batches` + `process` are the
fan-out path: a unit's items are claimed in `work_claim` before the stage runs them. The flows map a
task over the units; `run_stage` (what `photoshape run` calls) processes them one after another in
its own process, so both share one up-to-date check. A stage that does not fan out takes one
stage-level claim (item "stage") for the whole run, and so does a fan-out stage's finishing step,
so a second concurrent run is blocked instead of duplicating it. Items another live worker holds are
reported in `StageReport.blocked`; `run_all` stops there, or with `wait` polls until they are free
and does them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.db import claims
from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow
from photoshape_flow.db.heartbeat import Heartbeat
from photoshape_flow.db.holder import this_process
from photoshape_flow.faults import fault_point
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.progress import StageProgress
from photoshape_flow.pipeline.report import Blocked, StageReport, blocked_by
from photoshape_flow.pipeline.runs import mark_dead_runs
from photoshape_flow.pipeline.work import WorkUnit, claim_hash, item_hash
from photoshape_flow.profiles import Profile, ResolvedProfile, resolve_profile
from photoshape_flow.progress_sink import counted, labelled, nested
from photoshape_flow.stages.registry import REGISTRY, Stage, get_stage

log = logging.getLogger(__name__)

STAGE_ITEM = "stage"  # the one item key of a stage-level claim (stages that do not fan out)
WAIT_POLL_SECONDS = 5.0  # how often `wait` looks whether blocked items are free


class StageBlocked(Exception):
    """`run_all` stopped: another live worker holds items of this stage (see `report.blocked`)."""

    def __init__(self, report: StageReport, reports: list[StageReport]) -> None:
        super().__init__(blocked_line(report))
        self.report = report
        self.reports = reports


class StageFailed(Exception):
    """`run_all` stopped: a stage could not run on what it was given (its ValueError, the project's one-line
    refusal, e.g. no usable shape yet), named with the stage; `reports` are the stages done before it."""

    def __init__(self, stage: str, error: ValueError, reports: list[StageReport]) -> None:
        super().__init__(f"{stage}: {error}")
        self.stage = stage
        self.reports = reports


def blocked_line(report: StageReport, hint: str = "; not done by this run (use --wait to wait for them)") -> str:
    """One line for people: how many items, held by whom, until when."""
    b = report.blocked
    until = f" until {b.until.strftime('%Y-%m-%d %H:%M:%S UTC')}" if b.until is not None else ""
    return (f"{report.stage}: {b.count} item{'s' if b.count != 1 else ''} held by another live worker "
            f"({', '.join(b.holders) or 'unknown'}){until}{hint}")


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
    """One stage with its section of the profile, through the claims; `work` limits it to a unit (or
    an ingest request). A fan-out stage processes its planned units in this process, then finishes."""
    stage = get_stage(name)
    resolved = _resolved(profile)
    log.info("stage %s (profile %s) starting", name, resolved.name)
    named = replace(ctx, progress=labelled(ctx.progress, name))  # its loops' lines name the stage
    if isinstance(work, WorkUnit):
        report = process(name, work, resolved, named)
    elif stage.fans_out:
        report = _timed(lambda: _fan_out_here(stage, resolved, ctx))
    else:
        cfg = stage.config(resolved.profile)
        report = _timed(lambda: _exclusively(name, name, named, lambda: stage.run(named, cfg, work)))
    log.info("stage %s finished in %.1f s: %d done, %d skipped, %d failed, %d rejected, %d blocked", name,
             report.seconds, report.done, report.skipped, report.failed, report.rejected, report.blocked.count)
    return report


def _fan_out_here(stage: Stage, resolved: ResolvedProfile, ctx: StageContext) -> StageReport:
    """Every planned unit claimed and processed one after another, then the finishing step, unless items
    are blocked: the finishing step would see partial results (the holder's own run finishes after them).

    Progress: several units are one loop (`<stage> batches`), each unit's own loops nested in it
    (`<stage> batch 3/20: training renders`); a single unit's loops are named by the stage alone.
    """
    report = StageReport(stage.name)
    named = replace(ctx, progress=labelled(ctx.progress, stage.name))
    units = plan_batches(stage.name, resolved, ctx)
    if len(units) == 1:
        report = report.merge(process(stage.name, units[0], resolved, named))
    else:
        for k, unit in enumerate(counted(ctx.progress, f"{stage.name} batches", units), start=1):
            batch = replace(ctx, progress=nested(ctx.progress, f"{stage.name} batch {k}/{len(units)}"))
            report = report.merge(process(stage.name, unit, resolved, batch))
    if report.blocked.count:
        return report
    finished = finish(stage.name, resolved, named)
    return report if finished is None else report.merge(finished)


def _exclusively(name: str, claim_stage: str, ctx: StageContext, call: Callable[[], StageReport]) -> StageReport:
    """`call` under a stage-level claim, or stage `name`'s report blocked by the live worker holding it.

    The claim is a lock, not an up-to-date check (whole stages and finishing steps resume and skip
    by themselves): it is released when `call` ends, however it ends.
    """
    lease = ctx.settings.claim_lease_seconds
    with ctx.session() as session:
        won = claims.claim(session, claim_stage, [STAGE_ITEM], lease_seconds=lease, retry_failed=True)
        blocked = Blocked() if won else blocked_by(claims.live_holds(session, claim_stage, [STAGE_ITEM]))
    if not won:
        return StageReport(name, blocked=blocked)
    try:
        with Heartbeat(ctx.database_url, lease):
            return call()
    finally:
        with ctx.session() as session:
            claims.release(session, claim_stage, won)


def run_all(profile: str | Profile | ResolvedProfile, ctx: StageContext, names: Sequence[str] | None = None,
            ingest: Any = None, origin: str = "cli",
            on_stage: Callable[[StageReport], None] | None = None, wait: bool = False) -> list[StageReport]:
    """The stages in `names` (default: all) in registry order; the run and its profile are recorded.

    A stage left with items another live worker holds stops the run (`StageBlocked`, status
    `blocked`): later stages would work on partial input. With `wait`, the stage is run again every
    `WAIT_POLL_SECONDS` until nothing is blocked (the holder finished them, or died and they are
    taken over), then the run goes on.
    """
    resolved = _resolved(profile)
    wanted = [s.name for s in REGISTRY if names is None or s.name in names]
    run_id = start_run(ctx, resolved, wanted, origin)
    reports: list[StageReport] = []
    try:
        for name in wanted:
            work = ingest if name == "ingest" else None
            try:
                report = run_stage(name, resolved, ctx, work)
            except ValueError as exc:  # the stage refused its input in one line: say which stage, no traceback
                raise StageFailed(name, exc, reports) from exc
            if wait and report.blocked.count:  # said once; then polled quietly
                log.warning("waiting: %s", blocked_line(report, hint=""))
            while wait and report.blocked.count:
                time.sleep(WAIT_POLL_SECONDS)
                report = _after_wait(report, run_stage(name, resolved, ctx, work))
            reports.append(report)
            record_report(ctx, run_id, report)
            if on_stage is not None:
                on_stage(report)
            if report.blocked.count:
                raise StageBlocked(report, reports)
    except StageBlocked as exc:
        finish_run(ctx, run_id, str(exc), status="blocked")
        raise
    except BaseException as exc:
        finish_run(ctx, run_id, f"{type(exc).__name__}: {exc}")
        raise
    finish_run(ctx, run_id, None)
    return reports


def _after_wait(before: StageReport, again: StageReport) -> StageReport:
    """A stage's report over its rounds: work summed, skipped and blocked as the last round saw them."""
    merged = before.merge(again)
    merged.skipped, merged.blocked = again.skipped, again.blocked
    return merged


def start_run(ctx: StageContext, resolved: ResolvedProfile, stages: Sequence[str], origin: str) -> int:
    record = resolved.record()
    holder = this_process()
    with ctx.session() as session:
        mark_dead_runs(session)
        row = m.PipelineRun(origin=origin, profile_name=record["name"], overrides=record["overrides"],
                            profile=record["profile"], stages=list(stages), reports={}, status="running",
                            holder_host=holder.host, holder_pid=holder.pid, holder_started=holder.started)
        session.add(row)
        session.flush()
        return int(row.id)


def record_report(ctx: StageContext, run_id: int, report: StageReport) -> None:
    with ctx.session() as session:
        row = session.get(m.PipelineRun, run_id)
        if row is not None:
            row.reports = {**(row.reports or {}), report.stage: report.to_dict()}


def finish_run(ctx: StageContext, run_id: int, error: str | None, status: str | None = None) -> None:
    with ctx.session() as session:
        row = session.get(m.PipelineRun, run_id)
        if row is not None:
            row.status, row.error, row.finished_at = status or ("failed" if error else "ok"), error, utcnow()


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
    """Claim `unit`'s items, run the stage on those this worker won, mark them done (or failed).

    Each item's claim hash is the stage's `claim_hash` plus its `versions` key where the stage
    declares one, so a done item whose inputs changed is claimed again. Items another live worker
    holds are counted in `blocked`; the leases of the items won are renewed while the stage runs.
    """
    stage = get_stage(name)
    cfg = stage.config(_resolved(profile).profile)
    lease = ctx.settings.claim_lease_seconds
    if stage.claims_itself:
        with Heartbeat(ctx.database_url, lease):
            return _timed(lambda: stage.run(ctx, cfg, unit))
    claim_stage = f"{name}:{unit.part}"
    base = claim_hash(name, unit.part, cfg)
    versions = stage.versions(ctx, cfg, unit) if stage.versions is not None else {}
    hashes = {str(i): item_hash(base, versions.get(i)) for i in unit.ids}
    with ctx.session() as session:
        won = claims.claim(session, claim_stage, list(hashes), params_hash=hashes, lease_seconds=lease,
                           retry_failed=True)
        blocked = blocked_by(claims.live_holds(session, claim_stage, [k for k in hashes if k not in set(won)]))
    mine = tuple(int(k) for k in won)
    if not mine:
        return StageReport(name, skipped=len(unit.ids) - blocked.count, blocked=blocked)
    try:
        fault_point("claimed-before-result")
        with Heartbeat(ctx.database_url, lease):
            report = _timed(lambda: stage.run(ctx, cfg, WorkUnit(unit.part, mine)))
    except Exception as exc:
        with ctx.session() as session:
            for key in won:
                claims.fail(session, claim_stage, key, f"{type(exc).__name__}: {exc}")
        raise
    except BaseException:  # Ctrl-C, a stop: the items go back unclaimed, never left `claimed` by this run
        with ctx.session() as session:
            claims.release(session, claim_stage, won)
        raise
    with ctx.session() as session:
        claims.complete(session, claim_stage, won)
    report.skipped += len(unit.ids) - len(mine) - blocked.count
    report.blocked = blocked
    return report


def finish(name: str, profile: str | Profile | ResolvedProfile, ctx: StageContext) -> StageReport | None:
    """The stage's step after all its units (pairs of coarse alignment, the gallery of publish), under a
    stage-level claim (`NAME:finish`) so two workers finishing at once do not both do it."""
    stage = get_stage(name)
    if stage.finish is None:
        return None
    finish_step, cfg = stage.finish, stage.config(_resolved(profile).profile)
    return _timed(lambda: _exclusively(name, f"{name}:finish", ctx, lambda: finish_step(ctx, cfg)))


def stage_progress(session: Session) -> list[StageProgress]:
    """Every stage's done / pending / failed counts, in pipeline order."""
    return [stage.progress(session) for stage in REGISTRY]


