"""`photoshape gallery`: a static HTML site of the PhotoShapes (no network access needed to view it)."""

from __future__ import annotations

from pathlib import Path

import typer

from photoshape_flow.cli.common import console, fail, method_or_published, require_database
from photoshape_flow.cli.progress import cli_progress


def gallery(
    out: Path = typer.Argument(..., help="Folder to write the site into (index.html, pairs/, img/, downloads/)."),
    method: str | None = typer.Option(
        None, "--method", "-m",
        help="Method or exact method key to show. Default: the collection's publish.method (its last run's).",
    ),
    sheet: Path | None = typer.Option(None, "--sheet", help="Also write a contact-sheet PNG of the best candidates."),
    sheet_rows: int = typer.Option(6, "--sheet-rows", min=1, help="Candidates on the contact sheet."),
) -> None:
    """Write the gallery: exemplars, built-in and PhotoShape renders, materials, grades, downloads, licences.

    index.html lists the published PhotoShapes (those with a render); candidates.html the others, each
    with the command that renders it (photoshape run publish --pair N).
    """
    require_database()
    method = method_or_published(method)
    from photoshape_flow.publish.gallery_site import write_contact_sheet, write_gallery_site

    with cli_progress(console) as progress:
        site = write_gallery_site(out, method, progress=progress)
    console.print(f"gallery: {site.published} published PhotoShape(s); {site.waiting} candidate(s) without a "
                  f"render on {site.index.parent / 'candidates.html'}; open {site.index}", highlight=False)
    if sheet is not None:
        try:
            path = write_contact_sheet(sheet, method, rows=sheet_rows)
        except ValueError as exc:
            fail(f"{sheet}: {exc}")
        console.print(f"contact sheet: {path}")


def register(app: typer.Typer) -> None:
    app.command("gallery")(gallery)
