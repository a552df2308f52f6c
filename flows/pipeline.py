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
def photoshape_pipeline(profile: ProfileName = "default", stages: list[StageName] | None = None) -> dict[str, Any]:
    """Run the stages in canonical order; each resumes from what earlier runs recorded (incremental)."""
    wanted = set(stages or STAGE_NAMES)
    results: dict[str, Any] = {}
    times: dict[str, float] = {}
    for name in STAGE_NAMES:
        if name not in wanted:
            continue
        results[name], times[name] = timed(STAGE_FLOWS[name], profile=profile)
        get_run_logger().info("%s: %.1f s", name, times[name])
    publish_summary("photoshape pipeline run", times, {"profile": profile})
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
