"""`photoshape status`: rows per table, progress per stage, and the work claims held now."""

from __future__ import annotations

import typer
from rich.markup import escape
from rich.table import Table

from photoshape_flow.cli.common import console, require_database, shown_database_url

STAGE_COLUMNS = ("stage", "unit", "done", "pending", "failed", "rejected")


def status() -> None:
    """Counts per table and per stage: done / pending / failed / rejected; claims held and by whom."""
    from photoshape_flow.cli.claims_cmd import holds_table
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import claims
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.pipeline.progress import assumed_profile, rendering_progress, table_counts
    from photoshape_flow.pipeline.runs import mark_dead_runs
    from photoshape_flow.stages import stage_progress

    settings = get_settings()
    require_database()
    with session_scope() as session:
        mark_dead_runs(session)  # a killed run is counted as died, never as running
        stages = stage_progress(session)
        renderings = rendering_progress(session)
        tables = table_counts(session)
        assumed = assumed_profile(session)
        holds = claims.holds(session)
    console.print(f"database: {shown_database_url()}", highlight=False)
    console.print(f"data root: {settings.data_root.resolve()}", highlight=False)
    console.print(f"counts assume {assumed.describe()}", highlight=False, soft_wrap=True)
    st = Table(title="stages")
    for col in STAGE_COLUMNS:
        st.add_column(col, justify="left" if col in ("stage", "unit") else "right")
    for p in stages:
        st.add_row(*(str(getattr(p, col)) for col in STAGE_COLUMNS))
    console.print(st)
    if renderings:
        rt = Table(title="renderings, by the stage that made them")
        for col in ("kind", "stage", "ok", "failed", "rejected", "why rejected"):
            rt.add_column(col, justify="right" if col in ("ok", "failed", "rejected") else "left",
                          overflow="fold")
        for r in renderings:
            rt.add_row(r.kind, r.stage, str(r.ok), str(r.failed), str(r.rejected), escape(r.reasons_text()))
        console.print(rt)
    tt = Table(title="tables")
    tt.add_column("table")
    tt.add_column("rows", justify="right")
    tt.add_column("by status")
    for name, counts in tables.items():
        total = sum(counts.values())
        detail = "" if set(counts) == {"rows"} else ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))
        tt.add_row(name, str(total), detail)
    console.print(tt)
    if holds:  # work in progress elsewhere, or left behind by a dead worker (`photoshape claims release`)
        console.print(holds_table(holds))


def register(app: typer.Typer) -> None:
    app.command("status")(status)
