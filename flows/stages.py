"""One Prefect flow per canonical stage (names from photoshape_flow.vocab.STAGES).

Each flow is thin: it plans batches of IDs, maps a task over them and collects JSON summaries; the
work and its bookkeeping live in `photoshape_flow.pipeline`. Parameters are typed so they show up as
forms in the Prefect UI.
"""

from __future__ import annotations

import time
from typing import Any, Literal

from photoshape_flow.flows.artifacts import Progress, publish_candidates_table
from photoshape_flow.flows.tasks import (
    compute_pairs_task,
    gallery_task,
    plan_batches,
    process_batch,
    run_whole_stage,
    task_runner,
)
from prefect import flow, get_run_logger
from prefect.futures import as_completed

ProfileName = Literal["tiny", "small", "medium", "default", "paper"]
Method = Literal["classifier", "no-classifier", "color-match", "builtin"]


def fan_out(stage: str, profile: str, batch_size: int, part: str | None = None,
            method: str | None = None) -> list[dict[str, Any]]:
    """Map `process_batch` over the stage's batches, tracking progress in an artifact."""
    batches = plan_batches(stage, profile, batch_size, part)
    if not batches:
        return []
    progress = Progress(f"{stage}-{part or method or 'items'}", len(batches))
    futures = [process_batch.submit(stage, batch, profile, len(batch), part, method) for batch in batches]
    results = []
    for future in as_completed(futures):
        results.append(future.result())
        progress.step()
    return results


def _totals(results: list[dict[str, Any]]) -> dict[str, int]:
    return {
        "batches": len(results),
        "items": sum(r["requested"] for r in results),
        "claimed": sum(r["claimed"] for r in results),
    }


@flow(name="ingest", task_runner=task_runner())
def ingest(
    profile: ProfileName = "default",
    shapes: list[str] | None = None,
    exemplars: list[str] | None = None,
    materials: list[str] | None = None,
    envmaps: list[str] | None = None,
    source: str | None = None,
) -> dict[str, Any]:
    """Ingest the four collections; without paths, everything in <data_root>/inbox/{envmaps,materials,...}."""
    given = {"shapes": shapes, "exemplars": exemplars, "materials": materials, "envmaps": envmaps}
    options: dict[str, Any] = {}
    if any(given.values()):
        options["roots"] = {k: list(v) for k, v in given.items() if v}
    if source:
        options["source"] = source
    return run_whole_stage(stage="ingest", profile=profile, options=options)


@flow(name="coarse-alignment", task_runner=task_runner())
def coarse_alignment(profile: ProfileName = "default", batch_size: int = 8) -> dict[str, Any]:
    """Viewpoint sweeps and HOG descriptors per shape, exemplar descriptors, then exact retrieval -> pairs."""
    shapes = fan_out("coarse-alignment", profile, batch_size, part="shapes")
    exemplars = fan_out("coarse-alignment", profile, batch_size * 16, part="exemplars")
    pairs = compute_pairs_task(profile)
    return {"shapes": _totals(shapes), "exemplars": _totals(exemplars), "pairs": pairs}


@flow(name="fine-alignment", task_runner=task_runner())
def fine_alignment(profile: ProfileName = "default", batch_size: int = 32) -> dict[str, Any]:
    """Project each pair's part map, flow-warp it onto the exemplar, clean it with a dense CRF."""
    return _totals(fan_out("fine-alignment", profile, batch_size))


@flow(name="substances", task_runner=task_runner())
def substances(profile: ProfileName = "default") -> dict[str, Any]:
    """Bootstrap renders, the substance network, and a substance per aligned part."""
    return run_whole_stage(stage="substances", profile=profile)


@flow(name="training-renders", task_runner=task_runner())
def training_renders(profile: ProfileName = "default") -> dict[str, Any]:
    """Randomized renders conditioned on part substances (section 5.1), resumable."""
    return run_whole_stage(stage="training-renders", profile=profile)


@flow(name="training", task_runner=task_runner())
def training(profile: ProfileName = "default") -> dict[str, Any]:
    """Train (or resume, or fine-tune when materials were added) the material classifier."""
    return run_whole_stage(stage="training", profile=profile)


@flow(name="inference", task_runner=task_runner())
def inference(
    profile: ProfileName = "default",
    methods: list[Method] | None = None,
    batch_size: int = 64,
) -> dict[str, Any]:
    """Ranked materials per part for the classifier and the baselines (section 6.1)."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.pipeline.inference import resolve_classifier
    from photoshape_flow.pipeline.runner import get_profile

    out: dict[str, Any] = {}
    for method in methods or list(get_profile(profile).methods):
        if method == "classifier":
            with session_scope(get_settings().resolved_database_url) as session:
                if resolve_classifier(session) is None:
                    get_run_logger().warning("no trained material classifier yet: skipping the classifier")
                    continue
        out[method] = _totals(fan_out("inference", profile, batch_size, method=method))
    return out


@flow(name="publish", task_runner=task_runner())
def publish(profile: ProfileName = "default", batch_size: int = 8) -> dict[str, Any]:
    """PhotoShape renders and exports of the best pairs, the gallery, and a candidates table."""
    results = fan_out("publish", profile, batch_size)
    index = gallery_task()
    publish_candidates_table()
    return {**_totals(results), "gallery": index}


STAGE_FLOWS = {
    "ingest": ingest,
    "coarse-alignment": coarse_alignment,
    "fine-alignment": fine_alignment,
    "substances": substances,
    "training-renders": training_renders,
    "training": training,
    "inference": inference,
    "publish": publish,
}


def timed(fn: Any, **kwargs: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    result = fn(**kwargs)
    return result, time.perf_counter() - start
