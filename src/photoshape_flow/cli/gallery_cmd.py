"""`photoshape gallery`: a static HTML site of the PhotoShapes (no network access needed to view it)."""

from __future__ import annotations

from pathlib import Path

import typer

from photoshape_flow.cli.common import console


def gallery(
    out: Path = typer.Argument(..., help="Folder to write the site into (index.html, pairs/, img/, downloads/)."),
    method: str = typer.Option("classifier", "--method", "-m", help="Method or exact method key to show."),
) -> None:
    """Write the gallery: exemplars, built-in and PhotoShape renders, materials, grades, downloads, licences."""
    from photoshape_flow.pipeline.publish import write_gallery_site

    index = write_gallery_site(out, method)
    pages = len(list((out / "pairs").glob("*.html")))
    console.print(f"gallery: {pages} PhotoShape page(s); open {index}")


def register(app: typer.Typer) -> None:
    app.command("gallery")(gallery)
