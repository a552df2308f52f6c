"""`photoshape gallery`: a static HTML site of the PhotoShapes (no network access needed to view it),
and with --serve the same site on 127.0.0.1 with grading (`export.review_server`)."""

from __future__ import annotations

import signal
from collections.abc import Mapping
from pathlib import Path
from typing import Any

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
    serve: bool = typer.Option(
        False, "--serve",
        help="Then serve the site with grading: grade buttons and keys on each PhotoShape's page, written to the "
        "database like `photoshape grade`. Ctrl-C stops it and rewrites the folder with the new grades.",
    ),
    host: str = typer.Option("127.0.0.1", "--host", help="Address --serve binds (another than loopback: anyone "
                             "who reaches it can grade)."),
    port: int = typer.Option(8765, "--port", min=0, max=65535, help="Port of --serve (0: any free port)."),
    grader: str = typer.Option("user", "--grader", "-g", help="Who grades with --serve (as `photoshape grade`)."),
) -> None:
    """Write the gallery: exemplars, built-in and PhotoShape renders, materials, grades, downloads, licences.

    index.html lists the published PhotoShapes (those with a render); candidates.html the others, each
    with the command that renders it (photoshape run publish --pair N). With --serve, the site is
    then served on http://127.0.0.1:8765/ for grading until Ctrl-C.
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
    if serve:
        _serve(out, method, host, port, grader)


def _print_grade(grade: Mapping[str, Any]) -> None:
    console.print(f"pair {grade['pair_id']} ({grade['method_key']}): graded {grade['label']} by {grade['grader']} "
                  f"(grade {grade['grade_id']})", highlight=False, soft_wrap=True)


def _stop(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM stops the server as Ctrl-C does


def _serve(out: Path, method: str, host: str, port: int, grader: str) -> None:
    """Serve the written site until Ctrl-C or SIGTERM; then, if grades were given, rewrite the folder
    so its static pages show them too (the served pages read them from the database)."""
    from photoshape_flow.export.review_server import ReviewServer, is_loopback
    from photoshape_flow.publish.gallery_site import write_gallery_site
    from photoshape_flow.publish.review import DatabaseGrades

    try:
        server = ReviewServer(out, DatabaseGrades(method, grader), host, port, on_grade=_print_grade)
    except OSError as exc:
        fail(f"cannot serve on {host}:{port}: {exc.strerror or exc}; choose another --port (0: any free port)")
    console.print(f"review: serving {out} at {server.url} (grades by {grader}, method {method}); Ctrl-C stops",
                  highlight=False, soft_wrap=True)
    if not is_loopback(server.host):
        console.print(f"warning: bound to {host}: anyone who can reach this address can grade (no login)")
    previous = signal.signal(signal.SIGTERM, _stop)
    # Ctrl-C must stop it even when a non-interactive shell started it in the background with SIGINT ignored
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
    if server.graded:
        site = write_gallery_site(out, method)
        console.print(f"stopped: {server.graded} grade(s) written; {site.index} rewritten with them",
                      highlight=False, soft_wrap=True)
    else:
        console.print("stopped: no grade given", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("gallery")(gallery)
