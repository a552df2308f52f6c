"""`photoshape ingest shapes|exemplars|materials|envmaps PATH...`: bring the four collections in.

Each command shows a progress bar and ends with a summary (added / already present / replaced /
rejected) and one line per rejected input naming the file and the reason. When anything was rejected
the command exits with code 2 (`REJECTED_EXIT`) after saying how many and where the reasons are
(`--allow-rejected` exits 0 instead); errors that stop the command exit 1.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from photoshape_flow.cli.common import console, err_console, fail, require_database, shown
from photoshape_flow.cli.progress import cli_progress

ingest_app = typer.Typer(help="Ingest shapes, exemplars, materials and envmaps.", no_args_is_help=True)

PathsArg = typer.Argument(..., help="Files or folders (searched recursively).", show_default=False)
AttributionOpt = typer.Option(None, help="Attribution to record.")
AllowRejectedOpt = typer.Option(False, "--allow-rejected", help="Exit 0 even when inputs were rejected.")
# the former opt-in to exit code 2, now the default: still accepted so scripts that pass it keep working
StrictOpt = typer.Option(False, "--strict", hidden=True)
VerboseOpt = typer.Option(False, "--verbose", "-v", help="Log each item.")

REJECTED_EXIT = 2  # the exit code when inputs were rejected
# the table each verb records its items in, and its name column (a rejected row keeps its reason in `error`)
TABLES = {"shapes": ("shape", "source_id"), "exemplars": ("exemplar", "source_id"),
          "materials": ("material", "name"), "envmaps": ("envmap", "name")}


def _setup_logging(verbose: bool) -> None:
    package = logging.getLogger("photoshape_flow")
    if verbose:
        from rich.logging import RichHandler

        if not any(isinstance(h, RichHandler) for h in package.handlers):
            package.addHandler(RichHandler(console=err_console, show_path=False))
        package.setLevel(logging.INFO)
    elif not logging.getLogger().handlers and not package.handlers:
        # the summary prints every rejection; keep logging's last-resort handler from repeating them
        package.addHandler(logging.NullHandler())


def _start(verbose: bool, split: str | None = None) -> None:
    """What every ingest verb checks before its stage runs, so each refuses bad input the same way."""
    _setup_logging(verbose)
    require_database()
    if split not in (None, "train", "val"):
        fail(f"--split must be train or val, not {split!r}")


@contextmanager
def _progress(title: str) -> Iterator[Callable[[str, int, int], None]]:
    """A bar naming the file at hand on a terminal; otherwise the CLI's plain count/rate/ETA lines."""
    if not console.is_terminal:
        with cli_progress(console) as sink:
            yield lambda _label, done, total: sink(f"ingest {title}", done, total)
        return
    bar = Progress(
        TextColumn(f"[bold]{title}[/]"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        TextColumn("{task.description}"), console=console, transient=True,
    )
    task = bar.add_task("", total=None)

    def update(label: str, done: int, total: int) -> None:
        bar.update(task, completed=done, total=total, description=shown(Path(label).name[:50]))

    with bar:
        yield update


def print_announcement(summary: Any) -> None:
    """Whether the material-added event went out for the new materials (named), and what follows."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.events import MATERIAL_EVENT
    from photoshape_flow.masking import mask_password

    settings = get_settings()
    with session_scope(settings.resolved_database_url) as session:
        names = [n for (n,) in session.query(m.Material.name).filter(m.Material.id.in_(summary.new_material_ids))
                 .order_by(m.Material.name)]
    what = f"{len(names)} new material{'s' if len(names) != 1 else ''} ({shown(', '.join(names))})"
    if summary.announced:
        api = shown(mask_password(str(settings.effective_prefect_api_url)))
        console.print(f"announced {what}: event {MATERIAL_EVENT} sent to {api} "
                      "(the new-materials deployment re-fits and re-publishes)", highlight=False, soft_wrap=True)
    else:
        reason = ("no Prefect API configured" if not settings.effective_prefect_api_url
                  else "the Prefect API did not take it: see the warning above")
        console.print(f"[yellow]not announced[/]: {what}; {reason}; run `photoshape new-materials` to re-fit "
                      "and re-publish for them", highlight=False, soft_wrap=True)


def print_summary(summary: Any, allow_rejected: bool = False) -> None:
    """The summary table plus one line per rejection (and warnings), then the exit code.

    Exits with `REJECTED_EXIT` when anything was rejected (unless `allow_rejected`), after a line that
    says how many and where the reasons are: the lines above and the collection's table.
    """
    table = Table(title=f"ingest {summary.kind}", show_header=True)
    for column in ("added", "already present", "replaced", "rejected"):
        table.add_column(column, justify="right")
    table.add_row(str(len(summary.added)), str(len(summary.present)), str(len(summary.replaced)),
                  str(len(summary.rejected)))
    console.print(table)
    if getattr(summary, "announced", None) is not None:
        print_announcement(summary)
    if summary.duplicates:
        console.print(f"{len(summary.duplicates)} duplicates marked (excluded): "
                      + ", ".join(f"{a} -> {b}" for a, b in summary.duplicates[:20]), highlight=False)
    for label, message in summary.warnings:
        console.print(f"[yellow]warning[/] {shown(label)}: {shown(message)}", highlight=False)
    for label, reason in summary.skipped:
        console.print(f"[dim]skipped[/] {shown(label)}: {shown(reason)}", highlight=False)
    for label, reason in summary.rejected:
        err_console.print(f"[red]rejected[/] {shown(label)}: {shown(reason)}", highlight=False)
    if summary.rejected:
        table_name, key = TABLES[summary.kind]
        err_console.print(
            f"[red]{len(summary.rejected)} of {summary.total} inputs rejected[/]: the reasons are on the "
            f"'rejected' lines above and in table {table_name} (SELECT {key}, status, error FROM {table_name} "
            "WHERE status != 'ok')", highlight=False, soft_wrap=True)
        if not allow_rejected:
            raise typer.Exit(REJECTED_EXIT)


@ingest_app.command("shapes")
def shapes(
    paths: list[Path] = PathsArg,
    source: str | None = typer.Option(None, help="Source name (default: local, shapenet or sweethome3d)."),
    category: str | None = typer.Option(
        None, help="Catalogs/ShapeNet: keep these categories (comma-separated, e.g. chair,sofa). "
        "Plain files: the category to record."),
    name_filter: str | None = typer.Option(None, "--name-filter", help="Regular expression on names/ids/tags."),
    split: str | None = typer.Option(None, help="Force 'train' or 'val' (default: hash-based 90/10)."),
    license: str | None = typer.Option(None, "--license", help="Licence to record (catalogs bring their own)."),
    attribution: str | None = AttributionOpt,
    max_faces: int = typer.Option(500_000, help="Reject shapes with more triangles."),
    max_file_mb: float = typer.Option(100.0, help="Reject model files larger than this (MiB)."),
    timeout: float = typer.Option(600.0, help="Seconds per shape before the importer is killed."),
    isolate: bool = typer.Option(True, help="Parse in a child process (a crashing importer costs one item)."),
    allow_rejected: bool = AllowRejectedOpt,
    strict: bool = StrictOpt,
    verbose: bool = VerboseOpt,
) -> None:
    """OBJ+MTL, glTF/GLB, ShapeNetCore v2 trees and Sweet Home 3D catalogs (.sh3f)."""
    from photoshape_flow.ingest.ingest import IngestLimits, ingest_shapes

    _start(verbose, split)
    limits = IngestLimits(max_faces=max_faces, max_shape_bytes=int(max_file_mb * 1024 * 1024), timeout_s=timeout)
    try:
        with _progress("shapes") as progress:
            summary = ingest_shapes(paths, source=source, category=category, name_filter=name_filter, split=split,
                                    license=license, attribution=attribution, limits=limits, isolate=isolate,
                                    progress=progress)
    except ValueError as exc:
        fail(str(exc))
    print_summary(summary, allow_rejected)


@ingest_app.command("exemplars")
def exemplars(
    paths: list[Path] = PathsArg,
    source: str | None = typer.Option(None, help="Source name (default: local)."),
    category: str | None = typer.Option(None, help="Category to record (e.g. chair)."),
    size: int = typer.Option(512, help="Side of the stored square crop (paper: 1000; never upscaled)."),
    license: str | None = typer.Option(None, "--license", help="Licence to record."),
    attribution: str | None = AttributionOpt,
    source_url: str | None = typer.Option(None, help="Where the photos came from."),
    max_megapixels: float = typer.Option(64.0, help="Reject images with more pixels (decompression bombs)."),
    allow_rejected: bool = AllowRejectedOpt,
    strict: bool = StrictOpt,
    verbose: bool = VerboseOpt,
) -> None:
    """Product photos on white (JPEG/PNG/WebP): mask, square crop, resize, dedupe."""
    from photoshape_flow.ingest.ingest import IngestLimits, ingest_exemplars

    _start(verbose)
    if size < 16:
        fail("--size must be at least 16")
    limits = IngestLimits(max_image_pixels=int(max_megapixels * 1_000_000))
    with _progress("exemplars") as progress:
        summary = ingest_exemplars(paths, source=source, category=category, size=size, license=license,
                                   attribution=attribution, source_url=source_url, limits=limits, progress=progress)
    print_summary(summary, allow_rejected)


@ingest_app.command("materials")
def materials(
    paths: list[Path] = PathsArg,
    substance: str | None = typer.Option(None, help="Substance when neither sidecar nor folder name says."),
    source: str | None = typer.Option(None, help="Source name to record (sidecars take precedence)."),
    license: str | None = typer.Option(None, "--license", help="Licence to record (sidecars take precedence)."),
    attribution: str | None = AttributionOpt,
    previews: bool = typer.Option(True, help="Render sphere previews when the renderer is available."),
    allow_rejected: bool = AllowRejectedOpt,
    strict: bool = StrictOpt,
    verbose: bool = VerboseOpt,
) -> None:
    """SVBRDF folders (maps recognised by name + material.json/.toml) and analytic materials."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.flows.events import PrefectEvents
    from photoshape_flow.ingest.ingest import ingest_materials

    _start(verbose)
    with _progress("materials") as progress:
        summary = ingest_materials(paths, substance=substance, source=source, license=license,
                                   attribution=attribution, previews=previews, progress=progress,
                                   events=PrefectEvents(get_settings()))
    print_summary(summary, allow_rejected)


@ingest_app.command("envmaps")
def envmaps(
    paths: list[Path] = PathsArg,
    split: str | None = typer.Option(None, help="Force 'train' or 'val' (default: hash-based, ~10% val)."),
    license: str | None = typer.Option(None, "--license", help="Licence to record."),
    attribution: str | None = AttributionOpt,
    source_url: str | None = typer.Option(None, help="Where the maps came from."),
    allow_rejected: bool = AllowRejectedOpt,
    strict: bool = StrictOpt,
    verbose: bool = VerboseOpt,
) -> None:
    """Equirectangular HDR environment maps (.hdr, .exr)."""
    from photoshape_flow.ingest.ingest import ingest_envmaps

    _start(verbose, split)
    with _progress("envmaps") as progress:
        summary = ingest_envmaps(paths, split=split, license=license, attribution=attribution,
                                 source_url=source_url, progress=progress)
    print_summary(summary, allow_rejected)


def register(app: typer.Typer) -> None:
    app.add_typer(ingest_app, name="ingest")
