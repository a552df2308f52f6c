"""Alembic as product code: `photoshape db upgrade | downgrade | current | revision`.

The migration scripts live in the repository's `migrations/` folder and ship inside the package as
`photoshape_flow.migrations`, so an installed wheel can migrate a database without a checkout.
"""

from __future__ import annotations

import io
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory

import photoshape_flow.migrations as migrations
from photoshape_flow.config import get_settings
from photoshape_flow.db.session import get_engine


def migrations_dir() -> Path:
    return Path(migrations.__file__).parent


def alembic_config(url: str | None = None, stdout: io.TextIOBase | None = None) -> Config:
    config = Config(stdout=stdout) if stdout is not None else Config()
    config.set_main_option("script_location", str(migrations_dir()))
    config.set_main_option("sqlalchemy.url", (url or get_settings().resolved_database_url).replace("%", "%%"))
    config.set_main_option(
        "file_template", "%%(year)d_%%(month).2d_%%(day).2d_%%(hour).2d%%(minute).2d_%%(rev)s_%%(slug)s"
    )
    return config


def upgrade(url: str | None = None, revision: str = "head") -> None:
    command.upgrade(alembic_config(url), revision)


def downgrade(url: str | None = None, revision: str = "-1") -> None:
    command.downgrade(alembic_config(url), revision)


def revision(message: str, url: str | None = None, autogenerate: bool = True) -> None:
    command.revision(alembic_config(url), message=message, autogenerate=autogenerate)


def heads() -> list[str]:
    return list(ScriptDirectory.from_config(alembic_config()).get_heads())


def current_revision(url: str | None = None) -> str | None:
    """The revision the database is at (None: not migrated)."""
    with get_engine(url).connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def is_up_to_date(url: str | None = None) -> bool:
    return current_revision(url) in set(heads())
