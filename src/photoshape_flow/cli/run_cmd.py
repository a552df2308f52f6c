"""`photoshape run STAGE|all`: run pipeline stages in this process, without a Prefect server."""

from __future__ import annotations

import json

import typer
from rich.table import Table

from photoshape_flow.cli.common import console, fail, require_database, setup_logging
from photoshape_flow.vocab import STAGES


def print_results(results) -> None:  # type: ignore[no-untyped-def]
    table = Table(title="stages run")
    table.add_column("stage")
    table.add_column("seconds", justify="right")
    table.add_column("summary", overflow="fold")
    for r in results:
        text = json.dumps(r.summary, default=str)
        table.add_row(r.stage, f"{r.seconds:.1f}", text if len(text) < 400 else text[:400] + " ...")
    console.print(table)


def run(
    stage: str = typer.Argument(..., help=f"One of: {', '.join(STAGES)}, or 'all'."),
    profile: str = typer.Option("default", "--profile", "-p", help="tiny | small | medium | default | paper"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log each step."),
) -> None:
    """Run one stage (or all, in order); each resumes from what earlier runs recorded."""
    from photoshape_flow.pipeline.runner import PROFILES, run_all, run_stage

    setup_logging(verbose)
    if stage != "all" and stage not in STAGES:
        fail(f"unknown stage {stage!r}; choose from {', '.join(STAGES)} or all")
    if profile not in PROFILES:
        fail(f"unknown profile {profile!r}; choose from {', '.join(PROFILES)}")
    require_database()
    if stage == "all":
        results = run_all(profile, on_stage=lambda r: console.print(f"[green]done[/] {r.stage} ({r.seconds:.1f} s)"))
    else:
        results = [run_stage(stage, profile)]
    print_results(results)


def register(app: typer.Typer) -> None:
    app.command("run")(run)
