"""`photoshape claims list | release`: the work claims workers hold, and freeing stale ones.

A claim blocks its items for other workers until it is done, its lease runs out, or its holder is
found dead (same host). `release --stale` frees what nobody can be working on any more (lease run
out, or holder provably dead); `release --all` also frees live claims, for an operator who knows
the holder is gone (e.g. a worker on another machine that was switched off).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import typer
from rich.table import Table

from photoshape_flow.cli.common import console, fail, require_database

if TYPE_CHECKING:  # the ORM loads when a command runs, not for every `photoshape`
    from photoshape_flow.db.claims import Hold

claims_app = typer.Typer(help="Work claims held by workers: list them, free stale ones.", no_args_is_help=True)


def holds_table(holds: list[Hold]) -> Table:
    """One row per (claim stage, holder): items, lease expiry, and whether the holder is dead or expired."""
    table = Table(title="held claims")
    for column in ("stage", "items", "holder", "expires (UTC)", "state"):
        table.add_column(column, justify="right" if column == "items" else "left")
    for h in holds:
        state = "dead holder" if h.dead else "expired" if h.expired else "live"
        until = h.until.strftime("%Y-%m-%d %H:%M:%S") if h.until is not None else "-"
        table.add_row(h.stage, str(h.count), h.describe(), until, state)
    return table


@claims_app.command("list")
def list_claims(stage: str = typer.Option(None, "--stage", help="Only this stage (e.g. publish).")) -> None:
    """Claims held now, with their holder (host:pid and name) and lease expiry; dead holders marked."""
    from photoshape_flow.db import claims
    from photoshape_flow.db.session import session_scope

    require_database()
    with session_scope() as session:
        holds = claims.holds(session, stage)
    if not holds:
        console.print("no claims held")
        return
    console.print(holds_table(holds))


@claims_app.command("release")
def release(
    stage: str = typer.Option(None, "--stage", help="Only this stage (e.g. publish, training)."),
    stale: bool = typer.Option(False, "--stale", help="Free claims whose lease ran out or whose holder is dead "
                               "(the default)."),
    all_: bool = typer.Option(False, "--all", help="Free every held claim, live holders too."),
) -> None:
    """Free held claims so the next run does their items (done and failed items are kept)."""
    from photoshape_flow.db import claims
    from photoshape_flow.db.session import session_scope

    if stale and all_:
        fail("choose one of --stale and --all")
    require_database()
    with session_scope() as session:
        released = claims.release_held(session, stage, stale_only=not all_)
    what = "held" if all_ else "stale"
    console.print(f"released {released} {what} claim{'s' if released != 1 else ''}"
                  f"{f' of {stage}' if stage else ''}", highlight=False)


def register(app: typer.Typer) -> None:
    app.add_typer(claims_app, name="claims")
