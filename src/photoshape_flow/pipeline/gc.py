"""Blob garbage collection: every ref any row mentions is kept; the rest may go."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db.base import Base
from photoshape_flow.store import REF_PATTERN, BlobStore, GcReport


def _refs_in(value: Any) -> Iterator[str]:
    if isinstance(value, str):
        if REF_PATTERN.match(value):
            yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _refs_in(item)
    elif isinstance(value, list | tuple):
        for item in value:
            yield from _refs_in(item)


def referenced_refs(session: Session) -> set[str]:
    """All blob refs held by any row: `*_blob` columns, `blob` and every JSON column."""
    refs: set[str] = set()
    for table in Base.metadata.sorted_tables:
        columns = [
            c for c in table.columns if c.name.endswith("_blob") or c.name == "blob" or isinstance(c.type, sa.JSON)
        ]
        if not columns:
            continue
        for row in session.execute(sa.select(*columns)):
            for value in row:
                refs.update(_refs_in(value))
    return refs


def collect_garbage(session: Session, store: BlobStore, grace_seconds: float, dry_run: bool = False) -> GcReport:
    return store.gc(referenced_refs(session), grace_seconds=grace_seconds, dry_run=dry_run)
