"""Thin Prefect tasks over the pipeline: IDs and profile names in, JSON summaries out.

No task receives a session, an array or a live object, so every task is cacheable, retryable and
runs unchanged in a Dask worker process. The task runner of the stage flows is chosen from the
settings: batches run one after another in the flow's process by default (Mitsuba renders in one
thread per process), or fan out to Dask worker processes (`PHOTOSHAPE_DASK_WORKERS` for a local
cluster, `PHOTOSHAPE_DASK_ADDRESS` for an existing one).
"""

from __future__ import annotations

import logging
from typing import Any

from prefect import get_run_logger, task
from prefect.task_runners import ThreadPoolTaskRunner

from photoshape_flow.config import get_settings


def task_runner() -> Any:
    """The task runner the settings ask for (see the module docstring)."""
    settings = get_settings()
    if settings.dask_address or settings.dask_workers:
        from prefect_dask import DaskTaskRunner

        if settings.dask_address:
            return DaskTaskRunner(address=settings.dask_address)
        return DaskTaskRunner(
            cluster_kwargs={"n_workers": settings.dask_workers, "threads_per_worker": 1, "processes": True}
        )
    return ThreadPoolTaskRunner(max_workers=1)


def _logger() -> logging.Logger | logging.LoggerAdapter:
    try:
        return get_run_logger()
    except Exception:  # called outside a run (unit tests through .fn)
        return logging.getLogger("photoshape_flow.flows")


@task(name="plan-batches", task_run_name="plan {stage} {part}")
def plan_batches(stage: str, profile: str, batch_size: int, part: str | None = None) -> list[list[int]]:
    """Batches of the item IDs a fanning-out stage works on."""
    from photoshape_flow.pipeline.work import plan

    batches = plan(stage, profile, batch_size=batch_size, part=part)
    _logger().info("%s: %d items in %d batches", stage, sum(map(len, batches)), len(batches))
    return batches


@task(name="process-batch", task_run_name="{stage} batch of {n}", retries=1, retry_delay_seconds=10)
def process_batch(stage: str, ids: list[int], profile: str, n: int, part: str | None = None,
                  method: str | None = None) -> dict[str, Any]:
    """Claim the batch's items and run the stage on those won (see pipeline.work)."""
    from photoshape_flow.pipeline.work import process

    summary = process(stage, ids, profile, part=part, method=method)
    _logger().info("%s: claimed %d of %d", stage, summary["claimed"], summary["requested"])
    return summary


@task(name="run-stage", task_run_name="{stage}")
def run_whole_stage(stage: str, profile: str, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """A stage that does not fan out (its pipeline function batches and resumes internally)."""
    from photoshape_flow.pipeline.runner import run_stage

    result = run_stage(stage, profile, **(options or {}))
    _logger().info("%s finished in %.1f s", stage, result.seconds)
    return {"seconds": result.seconds, "summary": result.summary}


@task(name="compute-pairs")
def compute_pairs_task(profile: str) -> dict[str, Any]:
    """Exact retrieval over all descriptors, inverted into per-shape pairs (section 4.1)."""
    from photoshape_flow.pipeline.coarse_alignment import CoarseConfig, compute_pairs
    from photoshape_flow.pipeline.runner import get_profile

    prof = get_profile(profile)
    return compute_pairs(config=CoarseConfig(exemplar_topk=prof.exemplar_topk, shape_topn=prof.shape_topn))


@task(name="write-gallery")
def gallery_task() -> str:
    from photoshape_flow.pipeline.gallery_site import write_gallery_site
    from photoshape_flow.pipeline.runner import gallery_dir

    return str(write_gallery_site(gallery_dir(get_settings())))
