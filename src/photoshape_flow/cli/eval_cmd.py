"""`photoshape eval`: score the pipeline's outputs against the demo ground truth."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from photoshape_flow.cli.common import console, fail, require_database


def print_metrics(metrics) -> None:  # type: ignore[no-untyped-def]
    from photoshape_flow.pipeline.evaluate import metrics_table

    table = Table(title="evaluation")
    for col in ("stage", "method", "metric", "value", "count"):
        table.add_column(col, justify="right" if col in ("value", "count") else "left")
    for row in metrics_table(metrics):
        value = "" if row["value"] is None else f"{row['value']:.4f}"
        count = "" if row["count"] is None else str(row["count"])
        table.add_row(row["stage"], row["method"], row["metric"], value, count)
    console.print(table)


def eval_command(
    groundtruth: Path = typer.Argument(None, help="groundtruth.json (default: the newest demo under the data root)."),
    run: str = typer.Option(None, help="Name of this evaluation run (default: eval-<timestamp>)."),
    stage: list[str] = typer.Option(None, "--stage", help="Only these stages (repeatable)."),
    source: str = typer.Option(None, help="Only exemplars of this ingest source (e.g. demo-small)."),
) -> None:
    """Compare pipeline outputs with ground truth; prints a table and stores it in `evaluation`."""
    require_database()
    from photoshape_flow.config import get_settings
    from photoshape_flow.demo import newest_groundtruth
    from photoshape_flow.pipeline.evaluate import EVAL_STAGES, run_evaluation

    if groundtruth is None:
        groundtruth = newest_groundtruth(get_settings().data_root)
        if groundtruth is None:
            fail("no ground truth given and no demo under the data root; run `photoshape demo` first")
    if not groundtruth.is_file():
        fail(f"{groundtruth}: no such file")
    bad = [s for s in stage or [] if s not in EVAL_STAGES]
    if bad:
        fail(f"cannot evaluate {', '.join(bad)}; choose from {', '.join(EVAL_STAGES)}")
    try:
        name, metrics = run_evaluation(groundtruth, run, stages=stage or EVAL_STAGES, exemplar_source=source)
    except ValueError as exc:
        fail(str(exc))
    print_metrics(metrics)
    console.print(f"stored as evaluation run [bold]{name}[/]")


def register(app: typer.Typer) -> None:
    app.command("eval")(eval_command)
