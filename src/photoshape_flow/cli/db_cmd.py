"""`photoshape db upgrade | downgrade | current | heads | revision`: schema migrations."""

from __future__ import annotations

from pathlib import Path

import typer

from photoshape_flow.cli.common import console, fail, shown_database_url

db_app = typer.Typer(help="Migrate the metadata database (Alembic).", no_args_is_help=True)


@db_app.command("upgrade")
def upgrade(revision: str = typer.Argument("head", help="Target revision.")) -> None:
    """Upgrade the database schema (creates the database file for SQLite)."""
    from photoshape_flow.db import migrate

    try:
        created = new_database_note()
        migrate.upgrade(revision=revision)
    except Exception as exc:  # surface connection errors as one line
        fail(f"upgrade failed: {exc}")
    if created:
        console.print(created, highlight=False, soft_wrap=True)
    console.print(f"database at revision [bold]{migrate.current_revision()}[/]")


def new_database_note() -> str | None:
    """One line to print when the upgrade creates a new database (a mistyped data root makes one), else None.

    New: the database has no tables at all (for SQLite the file is created on the first connection).
    """
    import sqlalchemy as sa

    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import get_engine

    if sa.inspect(get_engine()).get_table_names():
        return None
    url = sa.engine.make_url(get_settings().resolved_database_url)
    if url.get_backend_name() == "sqlite" and url.database not in (None, "", ":memory:"):
        where, setting = str(Path(url.database).resolve()), "PHOTOSHAPE_DATA_ROOT"
    else:
        where, setting = shown_database_url(), "PHOTOSHAPE_DATABASE_URL"
    return f"created a new database at {where} (it was empty; check {setting} if you meant an existing one)"


@db_app.command("downgrade")
def downgrade(revision: str = typer.Argument("-1", help="Target revision, e.g. -1 or base.")) -> None:
    """Downgrade the database schema."""
    from photoshape_flow.db import migrate

    migrate.downgrade(revision=revision)
    console.print(f"database at revision [bold]{migrate.current_revision()}[/]")


@db_app.command("current")
def current() -> None:
    """Show the database's revision and whether it is the head."""
    from photoshape_flow.db import migrate

    rev = migrate.current_revision()
    heads = migrate.heads()
    state = "up to date" if rev in heads else f"behind head {', '.join(heads)}"
    console.print(f"{shown_database_url()}: revision {rev} ({state})", highlight=False)


@db_app.command("heads")
def heads() -> None:
    """Show the head revision(s) of the migration scripts (a linear history has one)."""
    from photoshape_flow.db import migrate

    for head in migrate.heads():
        console.print(head)


@db_app.command("revision")
def revision(
    message: str = typer.Option(..., "-m", "--message", help="What the migration changes."),
    autogenerate: bool = typer.Option(True, help="Diff the models against the database."),
) -> None:
    """Create a new migration script in migrations/versions (developers)."""
    from photoshape_flow.db import migrate

    migrate.revision(message, autogenerate=autogenerate)


def register(app: typer.Typer) -> None:
    app.add_typer(db_app, name="db")
