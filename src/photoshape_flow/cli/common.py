"""Helpers shared by the CLI verbs: console, one-line errors, settings/store/session access."""

from __future__ import annotations

from typing import NoReturn

import typer
from rich.console import Console
from rich.markup import escape

from photoshape_flow.export.text import one_line
from photoshape_flow.masking import install_password_masking, mask_password

console = Console()
err_console = Console(stderr=True)


def shown(value: object) -> str:
    """Text from data (file names, reasons, names) safe to print with rich: one line, no control or
    bidi character (`export.text.one_line`, the one sanitiser), and no square bracket read as markup."""
    return escape(one_line(value))


def fail(message: str, code: int = 1) -> NoReturn:
    """Print a one-line error and exit non-zero (database passwords masked, whatever the message quotes)."""
    err_console.print(f"[bold red]error:[/] {shown(mask_password(message))}", highlight=False)
    raise typer.Exit(code)


def setup_logging(verbose: bool) -> None:
    """Log pipeline steps to stderr (INFO with --verbose, otherwise warnings only)."""
    import logging

    from rich.logging import RichHandler

    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(name)s: %(message)s",
        handlers=[RichHandler(console=err_console, show_path=False)],
        force=True,
    )
    install_password_masking()  # the new handler masks passwords too


def get_store():  # type: ignore[no-untyped-def]
    from photoshape_flow.store import default_store

    return default_store()


def shown_database_url() -> str:
    """The database URL in effect, as every verb prints it: password masked."""
    from photoshape_flow.config import get_settings

    return mask_password(get_settings().resolved_database_url)


def require_database() -> None:
    """Fail with one line when the database cannot be reached or is not migrated to the head."""
    from photoshape_flow.db import migrate

    url = shown_database_url()
    try:
        up_to_date = migrate.is_up_to_date()
    except Exception as exc:
        fail(f"{url}: cannot connect ({str(exc).splitlines()[0]})")
    if not up_to_date:
        fail(f"{url}: not migrated; run `photoshape db upgrade`")


def method_or_published(method: str | None) -> str:
    """`--method` as given, else the method the collection publishes with (its last run's `publish.method`)."""
    if method:
        return method
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.pipeline.runs import published_method

    with session_scope(get_settings().resolved_database_url) as session:
        return published_method(session)


def resolve_profile_or_fail(name: str, overrides: list[str] | None):  # type: ignore[no-untyped-def]
    """`--profile NAME --set a.b=c ...` validated, or one line naming what is wrong."""
    from photoshape_flow.profiles import ProfileError, resolve_profile

    try:
        return resolve_profile(name, overrides or [])
    except ProfileError as exc:
        fail(str(exc))
