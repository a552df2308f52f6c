"""`evaluate`: score the database against a ground-truth file; the headline and the full table become
Prefect artifacts. Every parameter has a default (the last registered ground truth), so the
deployment's "Quick run" works."""

from __future__ import annotations

from typing import Any

from prefect import flow, get_run_logger, task
from prefect.artifacts import create_table_artifact

from photoshape_flow.masking import install_password_masking

install_password_masking()  # importing prefect configured its console and API log handlers: mask them too


@task(name="run-evaluation")
def run_evaluation_task(groundtruth: str | None, run: str | None, source: str | None) -> dict[str, Any]:
    from photoshape_flow.evaluation.tables import headline_rows, stage_rows
    from photoshape_flow.pipeline.evaluate import metrics_table, run_evaluation
    from photoshape_flow.pipeline.groundtruth_registry import resolve_groundtruth

    path, _ = resolve_groundtruth(groundtruth)
    groundtruth = str(path)
    logger = get_run_logger()
    name, metrics = run_evaluation(groundtruth, run, exemplar_source=source, on_problem=logger.warning)
    return {"run": name, "groundtruth": groundtruth, "headline": headline_rows(metrics),
            "stages": stage_rows(metrics), "table": metrics_table(metrics)}


@flow(name="evaluate")
def evaluate(groundtruth: str | None = None, run: str | None = None, source: str | None = None) -> dict[str, Any]:
    """Compare pipeline outputs with a ground-truth file (default: the last one evaluated, else the
    newest demo's groundtruth.json)."""
    result = run_evaluation_task(groundtruth, run, source)
    about = f"evaluation run {result['run']} against {result['groundtruth']}"
    for key, rows, what in (("photoshape-evaluation-headline", result["headline"], "ours vs each baseline"),
                            ("photoshape-evaluation-stages", result["stages"], "shared stages"),
                            ("photoshape-evaluation", result["table"], "every figure")):
        if rows:
            create_table_artifact(table=rows, key=key, description=f"{about}: {what}")
    get_run_logger().info("%s: %d metrics", about, len(result["table"]))
    return result
