"""`photoshape eval`: score the pipeline's outputs against a ground-truth file (docs/evaluation.md)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from photoshape_flow.cli.common import console, fail, require_database


def print_rows(title: str, rows: Sequence[dict[str, str]]) -> None:
    """A table of plain-string rows (the headline tables); nothing when there are no rows."""
    if not rows:
        return
    table = Table(title=title, title_justify="left")
    for i, col in enumerate(rows[0]):  # the first column names the row: never cut
        table.add_column(col, justify="left" if i == 0 else "right", no_wrap=i == 0)
    for row in rows:
        table.add_row(*row.values())
    console.print(table)


def print_metrics(metrics) -> None:  # type: ignore[no-untyped-def]
    """The headline (ours vs each baseline, the shared stages' main figures), then every figure."""
    from photoshape_flow.evaluation.tables import HEADLINE_TITLE, STAGES_TITLE, headline_rows, stage_rows
    from photoshape_flow.pipeline.evaluate import metrics_table

    print_rows(f"headline: {HEADLINE_TITLE}", headline_rows(metrics))
    print_rows(f"headline, {STAGES_TITLE}", stage_rows(metrics))
    table = Table(title="every figure", title_justify="left")
    for col in ("stage", "method", "metric", "value", "count", "95% interval"):
        table.add_column(col, justify="left" if col in ("stage", "method", "metric") else "right", overflow="fold",
                         no_wrap=col in ("metric", "95% interval"))  # metric names stay whole; stage and method fold
    for row in metrics_table(metrics):
        value = "" if row["value"] is None else f"{row['value']:.4f}"
        count = "" if row["count"] is None else str(row["count"])
        table.add_row(row["stage"], row["method"], row["metric"], value, count, row["95% interval"])
    console.print(table)


def print_problem(message: str) -> None:
    """One ground-truth entry left out: one line, as the matcher wrote it (it ends in "skipped")."""
    console.print(f"[yellow]{escape(message)}[/]", highlight=False, soft_wrap=True)


def eval_command(
    path: Path = typer.Argument(None, metavar="[GROUNDTRUTH]", help="Same as --groundtruth."),
    groundtruth: Path = typer.Option(
        None, "--groundtruth", "-g",
        help="Ground-truth file (docs/evaluation.md). Default: the last one evaluated, else the newest demo's."),
    run: str = typer.Option(None, help="Name of this evaluation run (default: eval-<timestamp>)."),
    stage: list[str] = typer.Option(None, "--stage", help="Only these stages (repeatable)."),
    source: str = typer.Option(None, help="Only exemplars of this ingest source (e.g. demo-small)."),
) -> None:
    """Compare pipeline outputs with ground truth; prints a headline and every figure, stores them in
    `evaluation` (tagged with the file's sha256) and registers the file as the next default."""
    require_database()
    from photoshape_flow.pipeline.evaluate import EVAL_STAGES, run_evaluation
    from photoshape_flow.pipeline.groundtruth_registry import resolve_groundtruth

    if path is not None and groundtruth is not None and path != groundtruth:
        fail(f"two ground truths given ({path} and --groundtruth {groundtruth}); give one")
    try:
        chosen, defaulted = resolve_groundtruth(groundtruth or path)
    except ValueError as exc:
        fail(str(exc))
    if defaulted:
        console.print(f"ground truth: {chosen}", highlight=False)
    if not chosen.is_file():
        fail(f"{chosen}: no such file")
    bad = [s for s in stage or [] if s not in EVAL_STAGES]
    if bad:
        fail(f"cannot evaluate {', '.join(bad)}; choose from {', '.join(EVAL_STAGES)}")
    from photoshape_flow.cli.progress import cli_progress

    try:
        with cli_progress(console) as progress:
            name, metrics = run_evaluation(chosen, run, stages=stage or EVAL_STAGES, exemplar_source=source,
                                           on_problem=print_problem, progress=progress)
    except ValueError as exc:
        fail(str(exc))
    print_metrics(metrics)
    console.print(f"stored as evaluation run [bold]{name}[/]", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("eval")(eval_command)
