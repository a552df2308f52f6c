"""`photoshape eval`: score the pipeline's outputs against a ground-truth file (docs/evaluation.md)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from photoshape_flow.cli.common import console, fail, require_database

HEADLINE_LINE = ("headline: ours, then each baseline (accuracy per part: top-1, top-5, subst.; per pair: "
                 "re-render RMSE, SSIM, relit RMSE, lower is better; vs ours: top-1 gap [95% interval])")


def print_rows(title: str, rows: Sequence[dict[str, str]]) -> None:
    """A borderless table of plain-string rows (the headline tables) that fits 80 columns; nothing
    when there are no rows."""
    if not rows:
        return
    console.print(title, highlight=False)
    table = Table(box=None, padding=(0, 1, 0, 0), pad_edge=False, show_edge=False, header_style="bold")
    for i, col in enumerate(rows[0]):  # the first column names the row: never cut
        table.add_column(col, justify="left" if i == 0 else "right", no_wrap=True)
    for row in rows:
        table.add_row(*row.values())
    console.print(table)


def figures_file(run: str) -> Path:
    """Where `eval` writes every figure of `run`: <data_root>/evaluations/<run>.txt."""
    from photoshape_flow.config import get_settings

    safe = "".join(c if c.isalnum() or c in "-_." else "-" for c in run)
    return get_settings().data_root / "evaluations" / f"{safe}.txt"


def print_metrics(metrics, run: str) -> Path:  # type: ignore[no-untyped-def]
    """The headline (ours vs each baseline, the shared stages' main figures), then every figure to a
    file (`figures_file`) whose path is printed; returns it."""
    from photoshape_flow.evaluation.tables import figures_text, headline_rows, stage_rows

    rows = headline_rows(metrics)
    for row in rows:  # one line per method: the paired interval in brackets, no wrapping
        row["vs ours"] = row["vs ours"].replace("(", "[").replace(")", "]").replace(", ", ",")
    print_rows(HEADLINE_LINE, rows)
    print_rows("headline, shared stages", stage_rows(metrics))
    path = figures_file(run)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(figures_text(metrics, f"evaluation run {run}: every figure ({len(metrics)})"))
    console.print(f"every figure ({len(metrics)}): {path}", highlight=False, soft_wrap=True)
    return path


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
    """Compare pipeline outputs with ground truth; prints a headline, writes every figure to
    <data_root>/evaluations/<run>.txt, stores them in `evaluation` (tagged with the file's sha256) and
    registers the file as the next default."""
    require_database()
    from photoshape_flow.scoring.evaluate import EVAL_STAGES, run_evaluation
    from photoshape_flow.scoring.groundtruth_registry import resolve_groundtruth

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
    print_metrics(metrics, name)
    console.print(f"stored as evaluation run [bold]{name}[/] (table `evaluation`)", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("eval")(eval_command)
