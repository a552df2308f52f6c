"""`photoshape export`: write the downloads of PhotoShapes (the formats of `export.formats`, assignment.json)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from photoshape_flow.cli.common import (
    console,
    err_console,
    fail,
    method_or_published,
    require_database,
    shown,
)
from photoshape_flow.cli.progress import cli_progress
from photoshape_flow.export.formats import DEFAULT_FORMATS, EXPORTERS, parse_formats
from photoshape_flow.profiles import writing_stage


def export(
    pair_ids: list[int] = typer.Argument(None, help="Pair ids to export (default: every candidate of the method)."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder; each PhotoShape goes into <pair>-<method_key>/."),
    method: str | None = typer.Option(
        None, "--method", "-m",
        help="fit (materials chosen by rendering), classifier (each pair's newest classifier), builtin, "
        "no-classifier, color-match, or an exact method key such as classifier:3 or fit:3. Default: the "
        "collection's publish.method (its last run's).",
    ),
    formats: str = typer.Option(",".join(DEFAULT_FORMATS), "--format", "-f",
                                help=f"Comma-separated: {', '.join(EXPORTERS)}."),
    size: int | None = typer.Option(None, min=8, help="Film size written into the Mitsuba XML (default: the "
                                    "published render's, so the scene renders it again; 512 when unpublished)."),
    spp: int | None = typer.Option(None, min=1, help="Samples per pixel written into the Mitsuba XML (default: "
                                   "the published render's; 128 when unpublished)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Export PhotoShapes for use in other tools; assignment.json (licences included) always comes along."""
    require_database()
    method = method_or_published(method)
    from photoshape_flow.publish.downloads import export_candidates

    try:
        chosen = parse_formats(formats)
    except ValueError as exc:
        fail(str(exc))
    with cli_progress(console if not as_json else err_console) as progress:
        results = export_candidates(out, pair_ids or None, method, chosen, size=size, spp=spp, progress=progress)
    if not results:
        fail(f"no candidates for method {method!r}: run the stage that writes them first "
             f"(photoshape run {writing_stage(method)})")
    if as_json:
        console.print_json(json.dumps(results))
    else:
        table = Table(title=f"exports in {out}")
        for column in ("pair", "method key", "status", "files / error"):
            table.add_column(column)
        for r in results:
            detail = ", ".join(sorted(r["files"])) if r["status"] == "ok" else r["error"]
            table.add_row(str(r["pair_id"]), str(r["method_key"] or ""), r["status"], shown(detail))
        console.print(table)
    failed = [r for r in results if r["status"] != "ok"]
    if failed:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    app.command("export")(export)
