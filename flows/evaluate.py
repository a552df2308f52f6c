"""`evaluate`: score the database against a ground-truth file; the headline and the full table become
Prefect artifacts. Every parameter has a default (the last registered ground truth), so the
deployment's "Quick run" works.

The costly part (re-rendering each method's PhotoShape at every exemplar's camera) fans out like the
pipeline's stages: one task per batch of exemplars on the flow's task runner (Dask workers where
configured), each returning its exemplars' observations; the pooled figures and their bootstrap
intervals are computed once, over all exemplars, when every batch is back. The batches write
nothing, so they need no claims: a re-run scores again and replaces the run's rows.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from photoshape_flow.flows.artifacts import Progress
from photoshape_flow.flows.logs import forward_project_logs
from photoshape_flow.flows.tasks import task_runner
from prefect import flow, get_run_logger, task
from prefect.artifacts import create_table_artifact
from prefect.futures import as_completed

from photoshape_flow.evaluation.tables import headline_rows, stage_rows
from photoshape_flow.masking import install_password_masking
from photoshape_flow.scoring.evaluate import (
    EVAL_STAGES,
    evaluation_batches,
    merge_scores,
    metrics_table,
    run_evaluation,
    score_batch,
)
from photoshape_flow.scoring.groundtruth_registry import resolve_groundtruth

install_password_masking()  # importing prefect configured its console and API log handlers: mask them too

EvalStage = Literal[EVAL_STAGES]  # type: ignore[valid-type]  # a form's choice list in the Prefect UI
RERENDER_MAX_PAIRS = 200  # per method, as `photoshape eval`: shared among the batches by their size


@task(name="plan-evaluation")
def plan_evaluation(groundtruth: str | None, source: str | None, batch_size: int) -> dict[str, Any]:
    path, _ = resolve_groundtruth(groundtruth)
    return {"groundtruth": str(path), "batches": evaluation_batches(path, batch_size, exemplar_source=source)}


@task(name="evaluation-batch")
def evaluation_batch(groundtruth: str, source: str | None, exemplar_ids: list[int],
                     rerender_max_pairs: int) -> dict[str, Any]:
    forward_project_logs()
    return score_batch(groundtruth, exemplar_ids, exemplar_source=source, rerender_max_pairs=rerender_max_pairs)


@task(name="run-evaluation")
def run_evaluation_task(groundtruth: str, run: str | None, source: str | None, stages: list[str],
                        inference_scores: dict[str, Any] | None = None) -> dict[str, Any]:
    logger = get_run_logger()
    name, metrics = run_evaluation(groundtruth, run, stages=stages, exemplar_source=source,
                                   on_problem=logger.warning, inference_scores=inference_scores)
    return {"run": name, "groundtruth": groundtruth, "headline": headline_rows(metrics),
            "stages": stage_rows(metrics), "table": metrics_table(metrics)}


@flow(name="evaluate", task_runner=task_runner())
def evaluate(groundtruth: str | None = None, run: str | None = None, source: str | None = None,
             batch_size: int = 25, stages: list[EvalStage] | None = None) -> dict[str, Any]:
    """Compare pipeline outputs with a ground-truth file (default: the last one evaluated, else the
    newest demo's groundtruth.json); the inference figures are scored in batches of `batch_size`
    exemplars, one task each. `stages`: which stages to score (default: all)."""
    stages = list(stages or EVAL_STAGES)
    plan = plan_evaluation(groundtruth, source, batch_size)
    batches, path = (plan["batches"] if "inference" in stages else []), plan["groundtruth"]
    total = sum(len(b) for b in batches)
    progress = Progress("evaluate", len(batches))
    futures = [evaluation_batch.submit(path, source, ids, math.ceil(RERENDER_MAX_PAIRS * len(ids) / max(1, total)))
               for ids in batches]
    scored = []
    for future in as_completed(futures):
        scored.append(future.result())
        progress.step()
    result = run_evaluation_task(path, run, source, stages, merge_scores(scored) if batches else None)
    about = f"evaluation run {result['run']} against {result['groundtruth']}"
    for key, rows, what in (("photoshape-evaluation-headline", result["headline"], "ours vs each baseline"),
                            ("photoshape-evaluation-stages", result["stages"], "shared stages"),
                            ("photoshape-evaluation", result["table"], "every figure")):
        if rows:
            create_table_artifact(table=rows, key=key, description=f"{about}: {what}")
    get_run_logger().info("%s: %d metrics in %d batches", about, len(result["table"]), len(batches))
    return result
