"""Declarative base: naming convention, portable JSON, timestamps, shared column mixins."""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, registry

NAMING_CONVENTION = {
    "ix": "ix_%(table_name)s__%(column_0_N_name)s",
    "uq": "uq_%(table_name)s__%(column_0_N_name)s",
    "ck": "ck_%(table_name)s__%(constraint_name)s",
    "fk": "fk_%(table_name)s__%(column_0_name)s__%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

# JSONB on PostgreSQL (indexable, compact), plain JSON (TEXT) on SQLite.
JSONType = sa.JSON().with_variant(postgresql.JSONB(), "postgresql")


# Column types shared by the models.
Str = sa.String(255)
Short = sa.String(32)


def fk(target: str, ondelete: str = "CASCADE") -> sa.ForeignKey:
    """A foreign key that follows its row: deleting the target deletes (or, with SET NULL, unlinks) it."""
    return sa.ForeignKey(target, ondelete=ondelete)


def utcnow() -> dt.datetime:
    return dt.datetime.now(dt.UTC)


class Base(DeclarativeBase):
    registry = registry(
        metadata=sa.MetaData(naming_convention=NAMING_CONVENTION),
        type_annotation_map={
            dict[str, Any]: JSONType,
            list[Any]: JSONType,
            dt.datetime: sa.DateTime(timezone=True),
            # Double as SQLAlchemy 2.1 maps it and the migrations declare it; 2.0 (pinned for Prefect's
            # scheduler) would map float to Float, a different column type on SQLite.
            float: sa.Double(),
        },
    )


class TimestampMixin:
    created_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())
    updated_at: Mapped[dt.datetime] = mapped_column(
        default=utcnow, onupdate=utcnow, server_default=sa.func.now()
    )


class StatusMixin:
    """Outcome of the step that produced this row: ok, failed or rejected, with a one-line reason."""

    status: Mapped[str] = mapped_column(sa.String(16), default="ok", server_default="ok", index=True)
    error: Mapped[str | None] = mapped_column(sa.Text)


class ParamsHashMixin:
    """Hash of the inputs, settings and code version that produced the row.

    A stage recomputes rows whose hash differs from the one it would produce now, so a changed
    input or setting invalidates exactly what depends on it.
    """

    params_hash: Mapped[str] = mapped_column(sa.String(64), default="", server_default="")


class ExcludeMixin:
    """Curation: an excluded item stays queryable but no stage uses it."""

    exclude: Mapped[bool] = mapped_column(default=False, server_default=sa.false())
    exclude_reason: Mapped[str | None] = mapped_column(sa.Text)


class SourcedItemMixin:
    """An ingested item keyed by where it came from (`source`, `source_id`), with a name and category.

    `sort_order` keeps these columns first, in this order, as each table declared them before.
    """

    id: Mapped[int] = mapped_column(primary_key=True, sort_order=-1)
    source: Mapped[str] = mapped_column(sa.String(64), sort_order=-1)
    source_id: Mapped[str] = mapped_column(Str, sort_order=-1)
    name: Mapped[str | None] = mapped_column(Str, sort_order=-1)
    category: Mapped[str | None] = mapped_column(sa.String(64), index=True, sort_order=-1)


class ProvenanceMixin:
    """Where an ingested item came from, so licences travel into exports."""

    source_path: Mapped[str | None] = mapped_column(sa.Text)
    sha256: Mapped[str | None] = mapped_column(sa.String(64), index=True)
    license: Mapped[str | None] = mapped_column(sa.Text)
    attribution: Mapped[str | None] = mapped_column(sa.Text)
    source_url: Mapped[str | None] = mapped_column(sa.Text)
