"""Work claims with a lease: several workers share a stage without doing an item twice.

A worker claims a batch of item keys for a stage; each claim expires after a lease, so the items of
a killed worker are picked up again by the next run. Finished items are marked `done` (with the
params hash they were done with) and skipped by later runs unless the hash changes.

On PostgreSQL, concurrent claimers are serialised per row by the unique key (stage, item_key):
INSERT ... ON CONFLICT DO UPDATE ... WHERE <claimable> only takes a row that is free, expired, failed
(when retrying) or stale, and RETURNING tells the worker which rows it won. SQLite serialises
writers globally, which gives the same guarantee for one machine.
"""

from __future__ import annotations

import datetime as dt
import os
import socket
from collections.abc import Iterable, Sequence

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from photoshape_flow.db.base import utcnow
from photoshape_flow.db.models import WorkClaim

CLAIMED = "claimed"
DONE = "done"
FAILED = "failed"


def worker_id() -> str:
    """A name for this worker process, unique across machines."""
    return f"{socket.gethostname()}:{os.getpid()}"


def claim(
    session: Session,
    stage: str,
    item_keys: Sequence[str],
    *,
    params_hash: str = "",
    lease_seconds: float = 900,
    worker: str | None = None,
    retry_failed: bool = False,
) -> list[str]:
    """Claim those of `item_keys` that are free; returns the keys this worker now holds.

    An item is free when it has no claim row, its lease expired, it is done with another params hash
    (stale), or it failed and `retry_failed` is set. Commit the session right after claiming so other
    workers see the claims.
    """
    if not item_keys:
        return []
    worker = worker or worker_id()
    now = utcnow()
    expires = now + dt.timedelta(seconds=lease_seconds)
    table = WorkClaim.__table__
    dialect = session.get_bind().dialect.name
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    claimable = sa.or_(
        sa.and_(table.c.state == CLAIMED, table.c.lease_expires_at < now),
        sa.and_(table.c.state == DONE, table.c.params_hash != params_hash),
        sa.and_(table.c.state == FAILED, sa.literal(retry_failed)),
        sa.and_(table.c.state == FAILED, table.c.params_hash != params_hash),
    )
    won: list[str] = []
    for key in dict.fromkeys(item_keys):
        stmt = insert(table).values(
            stage=stage, item_key=key, state=CLAIMED, worker=worker, lease_expires_at=expires,
            attempts=1, params_hash=params_hash, created_at=now, updated_at=now,
        )
        stmt = stmt.on_conflict_do_update(
            index_elements=["stage", "item_key"],
            set_={
                "state": CLAIMED, "worker": worker, "lease_expires_at": expires, "error": None,
                "attempts": table.c.attempts + 1, "params_hash": params_hash, "updated_at": now,
            },
            where=claimable,
        ).returning(table.c.item_key)
        if session.execute(stmt).scalar_one_or_none() is not None:
            won.append(key)
    return won


def complete(session: Session, stage: str, item_keys: Iterable[str], *, worker: str | None = None) -> None:
    """Mark items done (only claims held by this worker, so an expired-and-retaken item is not touched)."""
    _finish(session, stage, item_keys, DONE, None, worker)


def fail(session: Session, stage: str, item_key: str, error: str, *, worker: str | None = None) -> None:
    _finish(session, stage, [item_key], FAILED, error[:2000], worker)


def _finish(
    session: Session, stage: str, item_keys: Iterable[str], state: str, error: str | None, worker: str | None
) -> None:
    keys = list(item_keys)
    if not keys:
        return
    table = WorkClaim.__table__
    session.execute(
        sa.update(table)
        .where(table.c.stage == stage, table.c.item_key.in_(keys), table.c.worker == (worker or worker_id()))
        .values(state=state, error=error, lease_expires_at=None, updated_at=utcnow())
    )


def release(session: Session, stage: str, item_keys: Iterable[str], *, worker: str | None = None) -> None:
    """Give claims back without finishing them (e.g. on a clean shutdown)."""
    table = WorkClaim.__table__
    session.execute(
        sa.delete(table).where(
            table.c.stage == stage,
            table.c.item_key.in_(list(item_keys)),
            table.c.state == CLAIMED,
            table.c.worker == (worker or worker_id()),
        )
    )


def counts(session: Session, stage: str | None = None) -> dict[tuple[str, str], int]:
    """(stage, state) -> number of items, expired claims counted as 'expired'."""
    table = WorkClaim.__table__
    now = utcnow()
    state = sa.case(
        (sa.and_(table.c.state == CLAIMED, table.c.lease_expires_at < now), sa.literal("expired")),
        else_=table.c.state,
    )
    query = sa.select(table.c.stage, state, sa.func.count()).group_by(table.c.stage, state)
    if stage is not None:
        query = query.where(table.c.stage == stage)
    return {(s, st): n for s, st, n in session.execute(query)}
