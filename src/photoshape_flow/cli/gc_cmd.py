"""`photoshape gc`: remove blobs no row references."""

from __future__ import annotations

import typer

from photoshape_flow.cli.common import console, get_store


def gc(
    dry_run: bool = typer.Option(False, "--dry-run", help="Only report what would be removed."),
    grace: float | None = typer.Option(None, help="Keep unreferenced blobs younger than this many seconds."),
) -> None:
    """Remove blobs that no database row references."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.pipeline.gc import collect_garbage

    settings = get_settings()
    with session_scope() as session:
        report = collect_garbage(
            session, get_store(), grace if grace is not None else settings.gc_grace_seconds, dry_run=dry_run
        )
    verb = "would remove" if dry_run else "removed"
    console.print(
        f"scanned {report.scanned} blobs, {verb} {report.removed} ({report.freed_bytes / 1e6:.1f} MB), "
        f"kept {report.kept_young} young unreferenced"
    )


def register(app: typer.Typer) -> None:
    app.command("gc")(gc)
