"""Work claims with a lease: several workers share a stage without doing an item twice.

A worker claims a batch of item keys for a stage; each claim expires after a lease, so the items of
a killed worker are picked up again by the next run. Finished items are marked `done` (with the
params hash they were done with) and skipped by later runs unless the hash changes.

On PostgreSQL, concurrent claimers are serialised per row by the unique key (stage, item_key):
INSERT ... ON CONFLICT DO UPDATE ... WHERE <claimable> only takes a row that is free, expired, failed
(when retrying) or stale, and RETURNING tells the worker which rows it won. SQLite serialises
writers globally, which gives the same guarantee for one machine.

Each claim records its holder (`db.holder`: host, pid, process start time, worker name). A claim
whose holder is provably dead (same host, process gone or its pid reused) is claimable at once; the
holder's liveness is checked by the claimer before its INSERT, and the conflict clause only takes
a row still held by that dead worker, so two claimers racing for a dead worker's items never both
win. A live holder renews its leases with `db.heartbeat.Heartbeat` while it works.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from photoshape_flow.db.base import utcnow
from photoshape_flow.db.holder import Holder, is_dead, this_process
from photoshape_flow.db.models import WorkClaim

CLAIMED = "claimed"
DONE = "done"
FAILED = "failed"


def worker_id() -> str:
    """A name for this worker process, unique across machines."""
    return this_process().worker


def claim(
    session: Session,
    stage: str,
    item_keys: Sequence[str],
    *,
    params_hash: str | Mapping[str, str] = "",
    lease_seconds: float = 900,
    worker: str | None = None,
    retry_failed: bool = False,
) -> list[str]:
    """Claim those of `item_keys` that are free; returns the keys this worker now holds.

    An item is free when it has no claim row, its lease expired, it is done with another params hash
    (stale), it failed and `retry_failed` is set, or its holder is provably dead. `params_hash` is
    one hash for every item or one per item key. Commit the session right after claiming so other
    workers see the claims.
    """
    if not item_keys:
        return []
    holder = this_process()
    worker = worker or holder.worker
    now = utcnow()
    expires = now + dt.timedelta(seconds=lease_seconds)
    table = WorkClaim.__table__
    dialect = session.get_bind().dialect.name
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    keys = list(dict.fromkeys(item_keys))
    dead = dead_workers(session, stage, keys)
    holder_values = {"holder_host": holder.host, "holder_pid": holder.pid, "holder_started": holder.started,
                     "holder_name": holder.name}
    won: list[str] = []
    for key in keys:
        digest = params_hash if isinstance(params_hash, str) else params_hash[key]
        claimable = sa.or_(
            sa.and_(table.c.state == CLAIMED, table.c.lease_expires_at < now),
            sa.and_(table.c.state == CLAIMED, table.c.worker.in_(dead)),
            sa.and_(table.c.state == DONE, table.c.params_hash != digest),
            sa.and_(table.c.state == FAILED, sa.literal(retry_failed)),
            sa.and_(table.c.state == FAILED, table.c.params_hash != digest),
        )
        stmt = insert(table).values(
            stage=stage, item_key=key, state=CLAIMED, worker=worker, lease_expires_at=expires,
            attempts=1, params_hash=digest, created_at=now, updated_at=now, **holder_values,
        )
        stmt = stmt.on_conflict_do_update(
            index_elements=["stage", "item_key"],
            set_={
                "state": CLAIMED, "worker": worker, "lease_expires_at": expires, "error": None,
                "attempts": table.c.attempts + 1, "params_hash": digest, "updated_at": now, **holder_values,
            },
            where=claimable,
        ).returning(table.c.item_key)
        if session.execute(stmt).scalar_one_or_none() is not None:
            won.append(key)
    return won


def dead_workers(session: Session, stage: str, item_keys: Sequence[str]) -> list[str]:
    """Workers holding unexpired claims on `item_keys` whose process is provably gone (same host)."""
    table = WorkClaim.__table__
    rows = session.execute(
        sa.select(table.c.worker, table.c.holder_host, table.c.holder_pid, table.c.holder_started).distinct()
        .where(table.c.stage == stage, table.c.item_key.in_(list(item_keys)), table.c.state == CLAIMED,
               table.c.lease_expires_at >= utcnow())
    )
    return [worker for worker, host, pid, started in rows if is_dead(host, pid, started)]


def renew(session: Session, lease_seconds: float, *, worker: str | None = None) -> int:
    """Push back the lease of every claim this worker holds (the heartbeat); returns how many."""
    table = WorkClaim.__table__
    now = utcnow()
    result = session.execute(
        sa.update(table).where(table.c.state == CLAIMED, table.c.worker == (worker or worker_id()))
        .values(lease_expires_at=now + dt.timedelta(seconds=lease_seconds), updated_at=now)
    )
    return int(getattr(result, "rowcount", 0) or 0)


@dataclass(frozen=True)
class Hold:
    """Claims one worker holds on one claim stage: how many, until when, and whether it is alive."""

    stage: str
    worker: str
    holder: Holder
    count: int
    until: dt.datetime | None
    dead: bool
    expired: bool

    def describe(self) -> str:
        """How people see a holder: "host:pid (worker name)"."""
        return f"{self.worker} ({self.holder.name})" if self.holder.name else self.worker

    @property
    def stale(self) -> bool:
        """Claimable by anyone: the lease ran out or the holder is provably gone."""
        return self.dead or self.expired


def holds(session: Session, stage: str | None = None, item_keys: Sequence[str] | None = None) -> list[Hold]:
    """Held (state `claimed`) claims grouped by claim stage and worker; `stage` also matches "stage:part"."""
    table = WorkClaim.__table__
    query = (
        sa.select(table.c.stage, table.c.worker, table.c.holder_host, table.c.holder_pid, table.c.holder_started,
                  table.c.holder_name, sa.func.count(), sa.func.max(table.c.lease_expires_at))
        .where(table.c.state == CLAIMED)
        .group_by(table.c.stage, table.c.worker, table.c.holder_host, table.c.holder_pid, table.c.holder_started,
                  table.c.holder_name)
        .order_by(table.c.stage, table.c.worker)
    )
    if stage is not None:
        query = query.where(sa.or_(table.c.stage == stage, table.c.stage.like(f"{stage}:%")))
    if item_keys is not None:
        query = query.where(table.c.item_key.in_(list(item_keys)))
    now = utcnow()
    out = []
    for claim_stage, worker, host, pid, started, name, count, until in session.execute(query):
        until = _aware(until)
        holder = Holder(host or "", pid or 0, started or "", name or "")
        out.append(Hold(claim_stage, worker, holder, int(count), until, is_dead(host, pid, started),
                        until is not None and until < now))
    return out


def live_holds(session: Session, stage: str, item_keys: Sequence[str]) -> list[Hold]:
    """Holds on `item_keys` of exactly `stage` that nobody may take: unexpired, holder alive (or elsewhere)."""
    if not item_keys:
        return []
    return [h for h in holds(session, stage, item_keys) if h.stage == stage and not h.stale]


def release_held(session: Session, stage: str | None = None, *, stale_only: bool = True) -> int:
    """Delete held claims (of `stage`, or all): only stale ones (expired or dead holder) unless told."""
    table = WorkClaim.__table__
    released = 0
    for hold in holds(session, stage):
        if stale_only and not hold.stale:
            continue
        condition = [table.c.stage == hold.stage, table.c.state == CLAIMED, table.c.worker == hold.worker]
        if stale_only and not hold.dead:
            condition.append(table.c.lease_expires_at < utcnow())
        result = session.execute(sa.delete(table).where(*condition))
        released += int(getattr(result, "rowcount", 0) or 0)
    return released


def _aware(value: dt.datetime | None) -> dt.datetime | None:
    """SQLite returns naive datetimes: they are UTC, like everything `utcnow` writes."""
    if value is not None and value.tzinfo is None:
        return value.replace(tzinfo=dt.UTC)
    return value


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
