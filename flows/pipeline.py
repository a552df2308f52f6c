"""`photoshape-pipeline` (every stage in order: the nightly run) and `new-materials` (the triggered
material-added re-run: fit then publish of the affected pairs, no retraining; D36).

Both run the registered stage flows one after another (each fans out and claims its own work) and
record the run and its resolved profile in `pipeline_run`, as `photoshape run` does. Without a
`profile` they use the one the collection was last run with (`pipeline.runs.effective_profile`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Literal

from photoshape_flow.flows.artifacts import candidate_rows, publish_candidates_table, publish_summary
from photoshape_flow.flows.events import stage_context
from photoshape_flow.flows.stages import STAGE_FLOWS, ProfileName, effective, timed
from photoshape_flow.flows.tasks import task_runner
from prefect import flow, get_run_logger

from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.fitting.changes import fit_changes, fit_snapshot
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.stages import REGISTRY, STAGE_NAMES, Blocked, StageReport, get_stage
from photoshape_flow.stages.new_materials import plan_material_rerun
from photoshape_flow.stages.rerun import ORIGIN
from photoshape_flow.stages.run import finish_run, record_report, start_run

StageName = Literal[STAGE_NAMES]  # type: ignore[valid-type]


def run_stage_flows(profile: str, overrides: list[str], names: Sequence[str], origin: str,
                    items: list[int] | None = None, details: Callable[[str], dict[str, Any]] | None = None
                    ) -> tuple[dict[str, Any], dict[str, float]]:
    """The stage flows `names` in order, recorded as one `pipeline_run`; (results, seconds) per stage.

    `items`: each stage that fans out runs on just these of its items (the material-added re-run's
    pairs: its stages fan out over pairs); a stage that does not fan out runs whole.
    `details(stage)`, called after each stage, adds to its recorded report (the re-run's
    changed-parts counts on `fit`).
    """
    ctx = stage_context()
    run_id = start_run(ctx, resolve_profile(profile, overrides), list(names), origin=origin)
    results: dict[str, Any] = {}
    times: dict[str, float] = {}
    try:
        for name in names:
            limit = {"items": items} if items is not None and get_stage(name).fans_out else {}
            results[name], times[name] = timed(STAGE_FLOWS[name], profile=profile, overrides=overrides, **limit)
            counts = {k: int(results[name].get(k) or 0) for k in ("done", "skipped", "failed", "rejected")}
            held = results[name].get("blocked") or 0  # a fan-out's total, or a whole stage's Blocked as JSON
            blocked = Blocked(int(held["count"] if isinstance(held, dict) else held))
            extra = details(name) if details is not None else {}
            results[name].update(extra)
            record_report(ctx, run_id, StageReport(name, seconds=times[name], blocked=blocked, details=extra,
                                                   **counts))
            if blocked.count:
                get_run_logger().warning("%s: %d items held by another live worker", name, blocked.count)
            get_run_logger().info("%s: %d done, %d skipped, %d failed in %.1f s", name, counts["done"],
                                  counts["skipped"], counts["failed"], times[name])
    except BaseException as exc:
        finish_run(ctx, run_id, f"{type(exc).__name__}: {exc}")
        raise
    finish_run(ctx, run_id, None)
    return results, times


@flow(name="photoshape-pipeline", task_runner=task_runner())
def photoshape_pipeline(profile: ProfileName | None = None, stages: list[StageName] | None = None,
                        overrides: list[str] | None = None) -> dict[str, Any]:
    """Run the stages in canonical order; each resumes from what earlier runs recorded (incremental).

    The nightly deployment: the full chain, so materials added since the last classifier are
    retrained on (substances, training renders, training, inference) before fit and publish.

    `profile` empty: the profile (and overrides) the collection was last run with, `default` at first.
    """
    name, sets = effective(profile, overrides)
    wanted = [s for s in STAGE_NAMES if s in set(stages or STAGE_NAMES)]
    results, times = run_stage_flows(name, sets, wanted, origin="flow")
    publish_summary("photoshape pipeline run", times, {"profile": name, "overrides": sets})
    return {"seconds": times, "results": results, "profile": name, "overrides": sets}


@flow(name="new-materials", task_runner=task_runner(), description=(
    "Materials were added: fit first (minutes), no retraining. `fit` re-ranks the parts whose candidate set "
    "the new materials join, `publish` re-renders those pairs with publish.method, the gallery is rewritten; "
    "the summary says how many parts changed. Retraining waits for the nightly run."))
def new_materials(profile: ProfileName | None = None, renders_per_material: int = 40,
                  overrides: list[str] | None = None) -> dict[str, Any]:
    """Materials were added: the triggered chain of `stages.new_materials` (D36), fit then publish.

    The new materials are found by querying the database (what the newest classifier does not know),
    not from the triggering event, so one debounced run covers a whole bulk import. `fit` runs on the
    pairs whose candidate set they join, so a new material can win a part without a retrain; publish
    re-renders those of them whose assignment set (of `publish.method`) changed, and the gallery is
    rewritten. Training and bootstrap renders grow by `renders_per_material` per new material in the
    recorded overrides, which the nightly run (the full chain: retrain, then fit, then publish) uses.
    """
    url = get_settings().resolved_database_url
    name, sets = effective(profile, overrides)
    with session_scope(url) as session:
        rerun = plan_material_rerun(session, name, sets, renders_per_material, registry=REGISTRY)
        before = fit_snapshot(session, rerun.fit_key, rerun.pairs)
    summary: dict[str, Any] = {"new_materials": rerun.new_ids, "new_material_names": rerun.new_names,
                               "previous_classifier_id": rerun.previous_classifier_id,
                               "profile": rerun.profile, "overrides": rerun.overrides, "stages": rerun.stages,
                               "pairs": len(rerun.pairs), "fit": rerun.fit_key}
    if not rerun.new_ids:
        get_run_logger().info("new materials: none since classifier %s", rerun.previous_classifier_id)
        return {**summary, "classifier_id": rerun.previous_classifier_id}
    get_run_logger().info("new materials %s: %s on %d pairs (no retraining) with profile %s %s",
                          ", ".join(rerun.new_names),
                          " -> ".join(rerun.stages), len(rerun.pairs), rerun.profile, rerun.overrides)

    def changes(stage: str) -> dict[str, Any]:
        if stage != "fit":
            return {}
        with session_scope(url) as session:
            after = fit_snapshot(session, rerun.fit_key, rerun.pairs)
        return {"changes": fit_changes(before, after, rerun.new_ids).as_dict()}

    results, times = run_stage_flows(rerun.profile, rerun.overrides, rerun.stages, origin=ORIGIN,
                                     items=rerun.pairs, details=changes)
    changed = (results.get("fit") or {}).get("changes", {})
    summary.update(classifier_id=rerun.previous_classifier_id, results=results, seconds=times, changes=changed)
    method = resolve_profile(rerun.profile, rerun.overrides).profile.publish.method
    wanted = set(rerun.pairs)
    rows = [r for r in candidate_rows(method=method) if r["pair_id"] in wanted]
    publish_candidates_table("new-material-candidates", rows, method=method)
    publish_summary("new materials re-run (fit first, no retraining)", times,
                    {"new materials": ", ".join(rerun.new_names),
                     "classifier (not retrained)": rerun.previous_classifier_id, "pairs re-fitted": len(rerun.pairs),
                     "published with": method, "profile": rerun.profile,
                     "overrides": rerun.overrides}, key="new-materials-summary", changes=changed)
    return summary
