"""Thin Prefect tasks over the stage registry: names, IDs and profile overrides in, JSON reports out.

No task receives a session, an array or a live object, so every task is cacheable, retryable and
runs unchanged in a Dask worker process. The task runner of the stage flows is chosen from the
settings: batches run one after another in the flow's process by default (Mitsuba renders in one
thread per process), or fan out to Dask worker processes (`PHOTOSHAPE_DASK_WORKERS` for a local
cluster, `PHOTOSHAPE_DASK_ADDRESS` for an existing one). A local cluster's dashboard binds
`PHOTOSHAPE_DASK_DASHBOARD_ADDRESS`, 127.0.0.1:8787 unless configured.
"""

from __future__ import annotations

import logging
from typing import Any

from photoshape_flow.flows.artifacts import ArtifactProgress
from photoshape_flow.flows.events import stage_context as _stage_context
from photoshape_flow.flows.logs import forward_project_logs
from prefect import get_run_logger, task
from prefect.task_runners import ThreadPoolTaskRunner

from photoshape_flow import stages
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db.holder import set_worker_name
from photoshape_flow.masking import install_password_masking
from photoshape_flow.profiles import resolve_profile

install_password_masking()  # importing prefect configured its console and API log handlers: mask them too


def task_runner() -> Any:
    """The task runner the settings ask for (see the module docstring)."""
    settings = get_settings()
    if settings.dask_address or settings.dask_workers:
        from prefect_dask import DaskTaskRunner

        if settings.dask_address:
            return DaskTaskRunner(address=settings.dask_address)
        return DaskTaskRunner(cluster_kwargs=local_cluster_kwargs(settings))
    return ThreadPoolTaskRunner(max_workers=1)


def local_cluster_kwargs(settings: Settings) -> dict[str, Any]:
    """The distributed `LocalCluster` arguments: single-threaded worker processes, and the dashboard
    on `settings.dask_dashboard_address` (127.0.0.1 by default, where LocalCluster's own default
    ":8787" would serve task arguments and worker logs on every interface)."""
    return {"n_workers": settings.dask_workers, "threads_per_worker": 1, "processes": True,
            "dashboard_address": settings.dask_dashboard_address}


def stage_context() -> Any:
    """The stage context inside a task: the project's log lines go to the task run in the UI, and its
    loops' progress to progress artifacts (`artifacts.ArtifactProgress`)."""
    forward_project_logs()
    return _stage_context(progress=ArtifactProgress())


def _logger() -> logging.Logger | logging.LoggerAdapter:
    try:
        return get_run_logger()
    except Exception:  # called outside a run (unit tests through .fn)
        return logging.getLogger("photoshape_flow.flows")


def _name_claims() -> None:
    """Claims made by this task name its flow run, so `photoshape status` shows which run holds them."""
    try:
        from prefect.runtime import flow_run

        name = flow_run.name
    except Exception:  # outside a run (unit tests through .fn)
        return
    if name:
        set_worker_name(f"prefect flow run {name}")


def _profile(profile: str, overrides: list[str] | None) -> Any:
    return resolve_profile(profile, overrides or [])


@task(name="plan-batches", task_run_name="plan {stage}")
def plan_batches(stage: str, profile: str, overrides: list[str] | None, batch_size: int | None) -> list[dict[str, Any]]:
    """Units of work of a fanning-out stage, as {part, ids} dicts."""
    units = stages.plan_batches(stage, _profile(profile, overrides), stage_context(), batch_size)
    _logger().info("%s: %d items in %d batches", stage, sum(len(u.ids) for u in units), len(units))
    return [{"part": u.part, "ids": list(u.ids)} for u in units]


@task(name="process-batch", task_run_name="{stage} {part} batch of {n}", retries=1, retry_delay_seconds=10)
def process_batch(stage: str, part: str, ids: list[int], profile: str, overrides: list[str] | None,
                  n: int) -> dict[str, Any]:
    """Claim the batch's items and run the stage on those won (see photoshape_flow.stages.run)."""
    _name_claims()
    report = stages.process(stage, stages.WorkUnit(part, tuple(ids)), _profile(profile, overrides), stage_context())
    _logger().info("%s %s: %d done, %d skipped, %d failed of %d", stage, part, report.done, report.skipped,
                   report.failed, n)
    if report.blocked.count:
        _logger().warning("%s %s: %d items held by another live worker (%s)", stage, part, report.blocked.count,
                          ", ".join(report.blocked.holders))
    return report.to_dict()


@task(name="finish-stage", task_run_name="finish {stage}")
def finish_stage(stage: str, profile: str, overrides: list[str] | None) -> dict[str, Any] | None:
    """The stage's step after all its batches (pairs of coarse alignment, the gallery of publish)."""
    report = stages.finish(stage, _profile(profile, overrides), stage_context())
    return None if report is None else report.to_dict()


@task(name="run-stage", task_run_name="{stage}")
def run_whole_stage(stage: str, profile: str, overrides: list[str] | None = None,
                    work: Any = None) -> dict[str, Any]:
    """A stage that does not fan out (its pipeline function batches and resumes internally)."""
    _name_claims()
    report = stages.run_stage(stage, _profile(profile, overrides), stage_context(), work)
    _logger().info("%s finished in %.1f s", stage, report.seconds)
    return report.to_dict()
