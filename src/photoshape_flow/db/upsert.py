"""Idempotent writes: INSERT ... ON CONFLICT on the natural key, on SQLite and PostgreSQL alike."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from photoshape_flow.db.base import Base, utcnow


def _insert_for(session: Session, table: sa.Table):  # type: ignore[no-untyped-def]
    dialect = session.get_bind().dialect.name
    if dialect == "postgresql":
        return postgresql.insert(table)
    if dialect == "sqlite":
        return sqlite.insert(table)
    raise NotImplementedError(f"upsert is not implemented for {dialect}")


def upsert(
    session: Session,
    model: type[Base],
    rows: Sequence[Mapping[str, Any]] | Mapping[str, Any],
    key: Iterable[str],
    update: Iterable[str] | None = None,
) -> list[int]:
    """Insert `rows`, or update the existing row with the same natural `key`; returns the ids.

    `update` names the columns to overwrite on conflict (default: every given column but the key);
    an empty list means insert-or-keep. Running the same upsert twice changes nothing.
    """
    if isinstance(rows, Mapping):
        rows = [rows]
    if not rows:
        return []
    table: sa.Table = model.__table__  # type: ignore[assignment]
    key = list(key)
    ids: list[int] = []
    for row in rows:
        values = dict(row)
        columns = [c for c in values if c not in key] if update is None else list(update)
        if "updated_at" in table.c and columns:
            values.setdefault("updated_at", utcnow())
            if "updated_at" not in columns:
                columns.append("updated_at")
        stmt = _insert_for(session, table).values(**values)
        if columns:
            stmt = stmt.on_conflict_do_update(
                index_elements=key, set_={c: stmt.excluded[c] for c in columns}
            )
        else:
            # DO UPDATE of a key column to itself so RETURNING yields the existing id.
            stmt = stmt.on_conflict_do_update(index_elements=key, set_={key[0]: stmt.excluded[key[0]]})
        ids.append(session.execute(stmt.returning(table.c.id)).scalar_one())
    return ids
