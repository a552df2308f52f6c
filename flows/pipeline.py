"""`photoshape-pipeline` (every stage in order) and `new-materials` (the material-added re-run)."""

from __future__ import annotations

from typing import Any, Literal

from photoshape_flow.flows.artifacts import candidate_rows, publish_candidates_table, publish_summary
from photoshape_flow.flows.stages import STAGE_FLOWS, ProfileName, timed
from photoshape_flow.flows.tasks import task_runner
from prefect import flow, get_run_logger

from photoshape_flow.stages import STAGE_NAMES

StageName = Literal[STAGE_NAMES]  # type: ignore[valid-type]


@flow(name="photoshape-pipeline", task_runner=task_runner())
def photoshape_pipeline(profile: ProfileName = "default", stages: list[StageName] | None = None,
                        overrides: list[str] | None = None) -> dict[str, Any]:
    """Run the stages in canonical order; each resumes from what earlier runs recorded (incremental).

    The resolved profile and each stage's counts are recorded in `pipeline_run`, as `photoshape run` does.
    """
    from photoshape_flow.flows.events import stage_context

    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.stages import Blocked, StageReport
    from photoshape_flow.stages.run import finish_run, record_report, start_run

    wanted = [name for name in STAGE_NAMES if name in set(stages or STAGE_NAMES)]
    ctx = stage_context()
    run_id = start_run(ctx, resolve_profile(profile, overrides or []), wanted, origin="flow")
    results: dict[str, Any] = {}
    times: dict[str, float] = {}
    try:
        for name in wanted:
            results[name], times[name] = timed(STAGE_FLOWS[name], profile=profile, overrides=overrides)
            counts = {k: int(results[name].get(k) or 0) for k in ("done", "skipped", "failed", "rejected")}
            held = results[name].get("blocked") or 0  # a fan-out's total, or a whole stage's Blocked as JSON
            blocked = Blocked(int(held["count"] if isinstance(held, dict) else held))
            record_report(ctx, run_id, StageReport(name, seconds=times[name], blocked=blocked, **counts))
            if blocked.count:
                get_run_logger().warning("%s: %d items held by another live worker", name, blocked.count)
            get_run_logger().info("%s: %.1f s", name, times[name])
    except BaseException as exc:
        finish_run(ctx, run_id, f"{type(exc).__name__}: {exc}")
        raise
    finish_run(ctx, run_id, None)
    publish_summary("photoshape pipeline run", times, {"profile": profile, "overrides": overrides or []})
    return {"seconds": times, "results": results}


@flow(name="new-materials", task_runner=task_runner())
def new_materials(profile: ProfileName = "default", renders_per_material: int = 40) -> dict[str, Any]:
    """Materials were added: render training data with them, fine-tune the classifier, re-infer every pair.

    The new materials are found by querying the database (what the newest classifier does not know),
    not from the triggering event, so one debounced run covers a whole bulk import.
    """
    from photoshape_flow.pipeline.new_materials import run_new_materials

    (summary, seconds) = timed(run_new_materials, profile=profile, renders_per_material=renders_per_material)
    get_run_logger().info("new materials %s -> classifier %s (%.1f s)", summary["new_materials"],
                          summary["classifier_id"], seconds)
    if summary["new_materials"]:
        rows = [r for r in candidate_rows() if r["method_key"] == f"classifier:{summary['classifier_id']}"]
        publish_candidates_table("new-material-candidates", rows)
        publish_summary("new materials re-run", {"new-materials": seconds},
                        {"new materials": summary["new_materials"], "classifier": summary["classifier_id"]},
                        key="new-materials-summary")
    return summary
