"""`photoshape run STAGE|all`: run pipeline stages in this process, without a Prefect server."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import reduce
from typing import TYPE_CHECKING, Any

import typer
from rich.table import Table

from photoshape_flow.cli.common import (
    console,
    err_console,
    fail,
    require_database,
    resolve_profile_or_fail,
    setup_logging,
)
from photoshape_flow.cli.progress import cli_progress
from photoshape_flow.profiles import PROFILES, writing_stage

BLOCKED_EXIT_CODE = 3  # another live worker holds items this run needed (see `photoshape status`)

if TYPE_CHECKING:  # the registry imports the ORM: loaded when a command runs, not for every `photoshape`
    from photoshape_flow.stages import StageReport


SUMMARY_COLUMNS = ("stage", "done", "skipped", "failed", "rejected", "blocked", "seconds")


def report_row(r: StageReport) -> tuple[str, ...]:
    """A report's cells: counts and seconds only, so no JSON ever lands in a cell."""
    return (r.stage, str(r.done), str(r.skipped), str(r.failed), str(r.rejected), str(r.blocked.count),
            f"{r.seconds:.1f}")


def print_reports(reports: Sequence[StageReport], title: str = "stages run") -> None:
    """One row per stage plus a total: counts and seconds (details stay in the `pipeline_run` row)."""
    table = Table(title=title)
    for column in SUMMARY_COLUMNS:
        table.add_column(column, justify="left" if column == "stage" else "right")
    for r in reports:
        table.add_row(*report_row(r))
    if len(reports) > 1:
        total = reduce(lambda a, b: a.merge(b), reports)
        table.add_section()
        table.add_row("total", *report_row(total)[1:], style="bold")
    console.print(table)


def run_reporting_blocked(call: Callable[[], list[StageReport]]) -> list[StageReport]:
    """`call` (a `run_all`), or, when it stopped at a stage another live worker holds, that stage's
    one line (how many items, by whom, until when) and exit code 3 after the table of what did run;
    when a stage refused its input (e.g. an empty collection), the table, one line naming the stage
    and the reason, and exit code 1."""
    from photoshape_flow.stages.run import StageBlocked, StageFailed

    try:
        return call()
    except StageBlocked as exc:
        print_reports(exc.reports)
        err_console.print(f"[bold yellow]blocked:[/] {exc}", highlight=False, soft_wrap=True)
        raise typer.Exit(BLOCKED_EXIT_CODE) from None
    except StageFailed as exc:
        if exc.reports:
            print_reports(exc.reports)
        err_console.print(f"[bold red]failed:[/] {exc}", highlight=False, soft_wrap=True)
        raise typer.Exit(1) from None


def profile_fields(data: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted path, value) of every leaf of a profile's JSON: the names `--set` accepts."""
    out: list[tuple[str, Any]] = []
    for key, value in data.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out += profile_fields(value, f"{path}.")
        elif path != "name":
            out.append((path, ",".join(map(str, value)) if isinstance(value, list) else value))
    return out


def run(
    stage: str = typer.Argument(..., help="A stage, in pipeline order: ingest, coarse-alignment, ... publish "
                                "(`photoshape status` lists them all), or 'all'."),
    profile: str = typer.Option("default", "--profile", "-p", help=" | ".join(PROFILES)),
    overrides: list[str] = typer.Option(None, "--set", help="Override a profile field, e.g. training.epochs=3 "
                                        "(repeatable; --show-profile lists the fields)."),
    show_profile: bool = typer.Option(False, "--show-profile", help="Print the resolved profile's fields and exit."),
    pairs: list[int] = typer.Option(None, "--pair", help="publish only: render and export these pairs' "
                                    "PhotoShapes, whatever their rank (repeatable), then rewrite the gallery."),
    wait: bool = typer.Option(False, "--wait", help="When another live worker holds some items, wait until "
                              "they are free and do them (default: say so and exit with code 3)."),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log each step."),
) -> None:
    """Run one stage (or all, in order); each resumes from what earlier runs recorded."""
    from photoshape_flow.flows.events import stage_context
    from photoshape_flow.stages import STAGE_NAMES, run_all

    setup_logging(verbose)
    if stage != "all" and stage not in STAGE_NAMES:
        fail(f"unknown stage {stage!r}; choose from {', '.join(STAGE_NAMES)} or all")
    if pairs and stage != "publish":
        fail(f"--pair applies to the publish stage only, not {stage!r}")
    resolved = resolve_profile_or_fail(profile, overrides)
    if show_profile:
        for path, value in profile_fields(resolved.profile.to_dict()):
            if stage == "all" or path.split(".")[0] == stage.replace("-", "_"):
                console.print(f"{path} = {value}", highlight=False)
        return
    require_database()
    with cli_progress(console) as progress:
        ctx = stage_context(progress=progress)
        if pairs:
            print_reports([publish_pairs(resolved, ctx, pairs)], title="pairs published")
            return
        reports = run_reporting_blocked(lambda: run_all(
            resolved, ctx, names=None if stage == "all" else [stage], wait=wait,
            on_stage=lambda r: console.print(f"[green]done[/] {r.stage} ({r.seconds:.1f} s)")))
    print_reports(reports)
    print_announcement(reports)
    if any(r.stage == "publish" for r in reports):
        print_outputs(ctx)
    exit_if_inputs_rejected(reports)


def print_announcement(reports: Sequence[StageReport]) -> None:
    """Whether ingest announced the materials it added (the material-added event), when it added any."""
    from photoshape_flow.events import MATERIAL_EVENT

    for r in reports:
        materials = r.details.get("materials") if r.stage == "ingest" and isinstance(r.details, dict) else None
        if not isinstance(materials, dict) or "announced" not in materials:
            continue
        added = materials.get("added", 0)
        console.print(f"ingest: {added} new material{'s' if added != 1 else ''} " + (
            f"announced ({MATERIAL_EVENT} sent)" if materials["announced"] else
            f"not announced (no Prefect API configured, or it did not answer): {MATERIAL_EVENT} not sent"),
            highlight=False, soft_wrap=True)


def print_outputs(ctx: Any) -> None:
    """Where publish's results are: the gallery's index page and the exports folder."""
    from photoshape_flow.publish.downloads import exports_root
    from photoshape_flow.publish.publish_stage import gallery_dir

    console.print(f"gallery:  {gallery_dir(ctx) / 'index.html'}", highlight=False, soft_wrap=True)
    console.print(f"exports:  {exports_root(ctx.settings)}", highlight=False, soft_wrap=True)


def exit_if_inputs_rejected(reports: Sequence[StageReport]) -> None:
    """One line per input the ingest stage rejected, then exit 2 (as `photoshape ingest` does).

    The run itself went on and is recorded as done: a poison file in the inbox costs its own line,
    never the other items or the later stages; the exit code tells a script that something was refused.
    """
    from photoshape_flow.cli.common import shown
    from photoshape_flow.cli.ingest_cmd import REJECTED_EXIT

    lines = [line for r in reports if r.stage == "ingest"
             for details in r.details.values() if isinstance(details, dict)
             for line in details.get("rejected", [])]
    if not lines:
        return
    for line in lines:
        err_console.print(f"[red]rejected[/] {shown(line)}", highlight=False)
    err_console.print(f"[red]{len(lines)} input{'s' if len(lines) != 1 else ''} rejected at ingest[/]: the "
                      "run went on without them; the reasons are on the 'rejected' lines above", highlight=False)
    raise typer.Exit(REJECTED_EXIT)


def publish_pairs(resolved: Any, ctx: Any, pairs: Sequence[int]) -> StageReport:
    """Publish the given pairs (a candidate the gallery lists without a render), then the gallery.

    Recorded as a run like any other. A pair that is no PhotoShape candidate (unknown, excluded, or
    without rank-1 assignments) gets one line and the others go on; none at all exits 1.
    """
    from photoshape_flow.publish.photoshapes import candidate_method_keys
    from photoshape_flow.stages import WorkUnit, finish, run_stage
    from photoshape_flow.stages.run import finish_run, record_report, start_run

    wanted = sorted(set(pairs))
    method = resolved.profile.publish.method
    with ctx.session() as session:
        found = {pair_id for pair_id, _ in candidate_method_keys(session, method, wanted)}
    for pair_id in wanted:
        if pair_id not in found:
            console.print(f"[yellow]pair {pair_id}: not a PhotoShape candidate (unknown, excluded, or no rank-1 "
                          f"{method} assignments: run {writing_stage(method)} first)[/]", highlight=False)
    if not found:
        fail("no pair to publish")
    run_id = start_run(ctx, resolved, ["publish"], "cli")
    try:
        report = run_stage("publish", resolved, ctx, WorkUnit("pairs", tuple(sorted(found))))
        gallery = finish("publish", resolved, ctx)
        if gallery is not None:
            report = report.merge(gallery)
        record_report(ctx, run_id, report)
    except BaseException as exc:
        finish_run(ctx, run_id, f"{type(exc).__name__}: {exc}")
        raise
    finish_run(ctx, run_id, None)
    return report


def register(app: typer.Typer) -> None:
    app.command("run")(run)
