"""`photoshape new-materials`: the material-added re-run in this process (what the automation runs).

Fit first, no retraining: `fit` on the pairs whose candidate set the new materials join, then publish
of those pairs with `publish.method` and the gallery (`stages.rerun`). Prints the stage table and how
many parts changed; the nightly run (or `photoshape run all`) retrains.
"""

from __future__ import annotations

import typer
from rich.table import Table

from photoshape_flow.cli.common import (
    console,
    fail,
    require_database,
    resolve_profile_or_fail,
    setup_logging,
    shown,
)
from photoshape_flow.cli.progress import cli_progress
from photoshape_flow.profiles import PROFILES


def new_materials(
    profile: str | None = typer.Option(None, "--profile", "-p", help=" | ".join(PROFILES) + " (default: the "
                                       "profile the collection was last run with)"),
    overrides: list[str] = typer.Option(None, "--set", help="Override a profile field, e.g. publish.method=fit."),
    renders_per_material: int = typer.Option(40, "--renders-per-material", min=0,
                                             help="Training and bootstrap renders added per new material, "
                                             "recorded for the nightly retraining."),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log each step."),
) -> None:
    """Re-fit and re-publish for materials the newest classifier does not know (no retraining)."""
    from photoshape_flow.cli.run_cmd import print_reports
    from photoshape_flow.flows.events import stage_context
    from photoshape_flow.pipeline.runs import effective_profile
    from photoshape_flow.stages import REGISTRY
    from photoshape_flow.stages.new_materials import plan_material_rerun
    from photoshape_flow.stages.rerun import run_material_rerun

    setup_logging(verbose)
    require_database()
    with cli_progress(console) as progress:
        ctx = stage_context(progress=progress)
        with ctx.session() as session:
            name, sets = effective_profile(session, profile, overrides or [])
            resolve_profile_or_fail(name, sets)
            rerun = plan_material_rerun(session, name, sets, renders_per_material, registry=REGISTRY)
        if not rerun.new_ids:
            console.print(f"no new materials since classifier {rerun.previous_classifier_id}: nothing to do")
            return
        if not rerun.fit_key:
            fail("no trained material classifier yet: run `photoshape run all` first")
        console.print(f"new materials {shown(', '.join(rerun.new_names))}: {' -> '.join(rerun.stages)} "
                      f"on {len(rerun.pairs)} pair(s), "
                      f"profile {rerun.profile}", highlight=False)
        reports, changes = run_material_rerun(rerun, ctx)
    print_reports(reports, title="material-added re-run")
    table = Table(title=f"parts changed ({rerun.fit_key})")
    for column in ("parts", "candidate set grew", "winner changed", "won by a new material"):
        table.add_column(column, justify="right")
    table.add_row(str(changes.parts), str(changes.grown), str(changes.changed), str(changes.won_by_new))
    console.print(table)


def register(app: typer.Typer) -> None:
    app.command("new-materials")(new_materials)
