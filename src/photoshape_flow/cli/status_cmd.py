"""`photoshape status`: rows per table and progress per stage."""

from __future__ import annotations

import typer
from rich.table import Table

from photoshape_flow.cli.common import console, require_database, shown_database_url

STAGE_COLUMNS = ("stage", "unit", "done", "pending", "failed", "rejected")


def status() -> None:
    """Counts per table and per stage: done / pending / failed / rejected."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.pipeline.progress import assumed_profile, table_counts
    from photoshape_flow.stages import stage_progress

    settings = get_settings()
    require_database()
    with session_scope() as session:
        stages = stage_progress(session)
        tables = table_counts(session)
        assumed = assumed_profile(session)
    console.print(f"database: {shown_database_url()}", highlight=False)
    console.print(f"data root: {settings.data_root.resolve()}", highlight=False)
    console.print(f"counts assume {assumed.describe()}", highlight=False, soft_wrap=True)
    st = Table(title="stages")
    for col in STAGE_COLUMNS:
        st.add_column(col, justify="left" if col in ("stage", "unit") else "right")
    for p in stages:
        st.add_row(*(str(getattr(p, col)) for col in STAGE_COLUMNS))
    console.print(st)
    tt = Table(title="tables")
    tt.add_column("table")
    tt.add_column("rows", justify="right")
    tt.add_column("by status")
    for name, counts in tables.items():
        total = sum(counts.values())
        detail = "" if set(counts) == {"rows"} else ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))
        tt.add_row(name, str(total), detail)
    console.print(tt)


def register(app: typer.Typer) -> None:
    app.command("status")(status)
