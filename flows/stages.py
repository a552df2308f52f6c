"""One Prefect flow per registered stage, made from `photoshape_flow.stages.REGISTRY`.

Each flow is thin: a stage that fans out plans units of work, maps a claimed task over them and
runs its finishing step; any other stage runs whole in one task. The work and its bookkeeping live
in the stages and the pipeline. Parameters are typed so they show up as forms in the Prefect UI;
`overrides` takes the CLI's `--set` syntax (e.g. `training.epochs=3`); without a `profile`, a flow
uses the profile (and overrides) the collection was last run with, `default` before the first run.
"""

from __future__ import annotations

import time
from typing import Any, Literal

from photoshape_flow.flows.artifacts import Progress, publish_candidates_table, publish_gallery_artifacts
from photoshape_flow.flows.logs import forward_project_logs
from photoshape_flow.flows.tasks import finish_stage, plan_batches, process_batch, run_whole_stage, task_runner
from prefect import Flow, flow
from prefect.futures import as_completed

from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.ingest.ingest_stage import IngestRequest
from photoshape_flow.pipeline.runs import effective_profile
from photoshape_flow.profiles import PROFILES
from photoshape_flow.stages import REGISTRY, Stage

ProfileName = Literal[tuple(PROFILES)]  # type: ignore[valid-type]  # the profile table's names


def effective(profile: str | None, overrides: list[str] | None) -> tuple[str, list[str]]:
    """(profile name, overrides) of a flow run: `profile=None` is the one the collection was last run with."""
    forward_project_logs()  # every flow calls this first: its own process forwards the project's logs
    with session_scope(get_settings().resolved_database_url) as session:
        return effective_profile(session, profile, overrides or [])


def fan_out(stage: str, profile: str, overrides: list[str] | None, batch_size: int | None,
            items: list[int] | None = None) -> dict[str, Any]:
    """Map `process_batch` over the stage's units (only `items` of them, when given), tracking progress
    in an artifact, then finish."""
    units = plan_batches(stage, profile, overrides, batch_size)
    if items is not None:  # the material-added re-run: the affected pairs only
        wanted = set(items)
        units = [u for u in ({**u, "ids": [i for i in u["ids"] if i in wanted]} for u in units) if u["ids"]]
    totals: dict[str, Any] = {"batches": len(units), "items": 0, "done": 0, "skipped": 0, "failed": 0, "rejected": 0,
                              "blocked": 0}
    if units:
        progress = Progress(stage, len(units))
        futures = [process_batch.submit(stage, u["part"], u["ids"], profile, overrides, len(u["ids"]))
                   for u in units]
        for future in as_completed(futures):
            report = future.result()
            for key in ("done", "skipped", "failed", "rejected"):
                totals[key] += report[key]
            totals["blocked"] += report["blocked"]["count"]  # held by another live worker (see its holders)
            progress.step()
        totals["items"] = sum(len(u["ids"]) for u in units)
    finished = finish_stage(stage, profile, overrides)
    if finished is not None:
        totals["finish"] = finished["details"]
    return totals


def _stage_flow(stage: Stage) -> Flow:
    """The flow of one registered stage (the ingest flow is written out below: it takes paths)."""
    name = stage.name

    if stage.fans_out:
        def body(profile: ProfileName | None = None, overrides: list[str] | None = None,
                 batch_size: int = stage.batch_size, items: list[int] | None = None) -> dict[str, Any]:
            """`items`: only these of the stage's planned items (None: all of them)."""
            result = fan_out(name, *effective(profile, overrides), batch_size, items)
            if name == "publish":  # what the UI shows of a publish: the candidates, the sheet, the gallery
                finished = result.get("finish") or {}
                publish_candidates_table(method=finished.get("method") or "classifier")
                publish_gallery_artifacts(finished.get("gallery"), finished.get("method"))
            return result
    else:
        def body(profile: ProfileName | None = None, overrides: list[str] | None = None  # type: ignore[misc]
                 ) -> dict[str, Any]:
            return run_whole_stage(name, *effective(profile, overrides))

    body.__name__ = name.replace("-", "_")
    body.__qualname__ = body.__name__
    return flow(name=name, description=stage.description, task_runner=task_runner())(body)


@flow(name="ingest", description=REGISTRY[0].description, task_runner=task_runner())
def ingest(
    profile: ProfileName | None = None,
    shapes: list[str] | None = None,
    exemplars: list[str] | None = None,
    materials: list[str] | None = None,
    envmaps: list[str] | None = None,
    source: str | None = None,
    overrides: list[str] | None = None,
) -> dict[str, Any]:
    """Ingest the four collections; without paths, everything in <data_root>/inbox/{envmaps,materials,...}."""
    given = {"shapes": shapes, "exemplars": exemplars, "materials": materials, "envmaps": envmaps}
    roots = {k: list(v) for k, v in given.items() if v} or None
    name, sets = effective(profile, overrides)
    return run_whole_stage(stage="ingest", profile=name, overrides=sets,
                           work=IngestRequest(roots=roots, source=source))


STAGE_FLOWS: dict[str, Flow] = {s.name: ingest if s.name == "ingest" else _stage_flow(s) for s in REGISTRY}
globals().update({f.fn.__name__: f for name, f in STAGE_FLOWS.items() if name != "ingest"})


def timed(fn: Any, **kwargs: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    result = fn(**kwargs)
    return result, time.perf_counter() - start
