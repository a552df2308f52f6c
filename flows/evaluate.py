"""`evaluate`: score the database against a demo ground truth; the table becomes a Prefect artifact."""

from __future__ import annotations

from typing import Any

from prefect import flow, get_run_logger, task
from prefect.artifacts import create_table_artifact

from photoshape_flow.masking import install_password_masking

install_password_masking()  # importing prefect configured its console and API log handlers: mask them too


@task(name="run-evaluation")
def run_evaluation_task(groundtruth: str, run: str | None, source: str | None) -> dict[str, Any]:
    from photoshape_flow.pipeline.evaluate import metrics_table, run_evaluation

    name, metrics = run_evaluation(groundtruth, run, exemplar_source=source)
    return {"run": name, "table": metrics_table(metrics)}


@flow(name="evaluate")
def evaluate(groundtruth: str, run: str | None = None, source: str | None = None) -> dict[str, Any]:
    """Compare pipeline outputs with a ground-truth manifest (e.g. <data_root>/demo/small/groundtruth.json)."""
    result = run_evaluation_task(groundtruth, run, source)
    create_table_artifact(table=result["table"], key="photoshape-evaluation",
                          description=f"evaluation run {result['run']} against {groundtruth}")
    get_run_logger().info("evaluation %s: %d metrics", result["run"], len(result["table"]))
    return result
