"""Alembic environment: URL from photoshape settings (or the caller), batch mode on SQLite."""

from __future__ import annotations

from alembic import context

from photoshape_flow.db import models  # noqa: F401  (registers every table on the metadata)
from photoshape_flow.db.base import Base
from photoshape_flow.db.session import make_engine
from photoshape_flow.db.views import CANDIDATE_VIEW

config = context.config
target_metadata = Base.metadata


def include_object(obj, name, type_, reflected, compare_to):  # type: ignore[no-untyped-def]
    # Views are created by migrations, not by the ORM; autogenerate must not see them as tables.
    return not (type_ == "table" and name == CANDIDATE_VIEW)


def run_migrations_offline() -> None:
    url = config.get_main_option("sqlalchemy.url")
    context.configure(
        url=url,
        target_metadata=target_metadata,
        literal_binds=True,
        render_as_batch=url.startswith("sqlite") if url else False,
        include_object=include_object,
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connectable = config.attributes.get("connection")
    if connectable is None:
        # make_engine creates the SQLite file's folder and applies the same pragmas as the pipeline.
        engine = make_engine(config.get_main_option("sqlalchemy.url"))
        try:
            with engine.connect() as connection:
                _run(connection)
        finally:
            engine.dispose()
    else:
        _run(connectable)


def _run(connection) -> None:  # type: ignore[no-untyped-def]
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
        include_object=include_object,
    )
    with context.begin_transaction():
        context.run_migrations()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
