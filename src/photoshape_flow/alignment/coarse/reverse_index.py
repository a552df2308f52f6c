"""The reverse index: per exemplar, its stored top-k shapes with their best view (`ExemplarMatch`).

One row per (exemplar, viewpoint set, descriptor, scope, rank), where scope is the category the
search was restricted to, or ''. Each row holds the shape, its best view and the squared distance,
``searched_at`` (when the exemplar's list was last searched) and ``params_hash`` over k, mode,
viewpoints, descriptor settings, the exemplar's feature and the category. An exemplar's rows are
replaced in one transaction; an unchanged list only gets a new ``searched_at``.
"""

from __future__ import annotations

import datetime as dt
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.index import Matches
from photoshape_flow.alignment.coarse.config import CoarseConfig
from photoshape_flow.alignment.coarse.viewpoint_sets import cameras_hash, config_viewpoint_set
from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow
from photoshape_flow.hashing import stable_hash


@dataclass(frozen=True)
class StoredList:
    """One exemplar's stored top-k list: (n, 3) [shape id, view index, squared distance], nearest first."""

    matches: np.ndarray
    params_hash: str | None  # None: the rows disagree
    searched_at: float  # seconds since the epoch
    complete: bool  # ranks are 1..n (no row lost to a deleted shape's cascade) and hashes agree


def epoch_seconds(value: dt.datetime | None) -> float:
    """Seconds since the epoch; naive values (SQLite) are UTC; None is before everything."""
    if value is None:
        return float("-inf")
    if value.tzinfo is None:
        value = value.replace(tzinfo=dt.UTC)
    return value.timestamp()


def match_scope(config: CoarseConfig) -> str:
    """`ExemplarMatch.scope` of a run: the category its search is restricted to, or ''."""
    return config.category or ""


def _match_filter(config: CoarseConfig, viewpoint_set_id: int) -> tuple[sa.ColumnElement[bool], ...]:
    """The `ExemplarMatch` rows of one reverse index: (viewpoint set, descriptor, scope)."""
    return (
        m.ExemplarMatch.viewpoint_set_id == viewpoint_set_id,
        m.ExemplarMatch.descriptor == config.hog.name,
        m.ExemplarMatch.scope == match_scope(config),
    )


def list_hash(config: CoarseConfig, vpset: m.ViewpointSet, feature_blob: str) -> str:
    """params_hash of one exemplar's list: what its search depends on."""
    return stable_hash(
        {
            "k": config.exemplar_topk,
            "mode": config.mode,
            "viewpoints": cameras_hash(vpset),
            "hog": config.hog.params_hash(),
            "feature": feature_blob,
            "category": config.category,
        }
    )


def stored_lists(session: Session, config: CoarseConfig, viewpoint_set_id: int) -> dict[int, StoredList]:
    """Every exemplar's stored list in the reverse index of `config` and the viewpoint set."""
    rows = session.execute(
        sa.select(
            m.ExemplarMatch.exemplar_id, m.ExemplarMatch.rank, m.ExemplarMatch.shape_id,
            m.ExemplarMatch.view_index, m.ExemplarMatch.distance, m.ExemplarMatch.params_hash,
            m.ExemplarMatch.searched_at,
        )
        .where(*_match_filter(config, viewpoint_set_id))
        .order_by(m.ExemplarMatch.exemplar_id, m.ExemplarMatch.rank)
    ).all()
    grouped: dict[int, list[Any]] = defaultdict(list)
    for row in rows:
        grouped[row.exemplar_id].append(row)
    out: dict[int, StoredList] = {}
    for eid, entries in grouped.items():
        hashes = {r.params_hash for r in entries}
        params_hash = next(iter(hashes)) if len(hashes) == 1 else None
        out[eid] = StoredList(
            matches=np.array([[r.shape_id, r.view_index, r.distance] for r in entries], np.float64).reshape(-1, 3),
            params_hash=params_hash,
            searched_at=min(epoch_seconds(r.searched_at) for r in entries),
            complete=params_hash is not None and [r.rank for r in entries] == list(range(1, len(entries) + 1)),
        )
    return out


def load_reverse_index(session: Session, config: CoarseConfig | None = None) -> dict[int, np.ndarray]:
    """Per exemplar id: its (n, 3) [shape id, view index, distance] list, nearest first."""
    config = config or CoarseConfig()
    vpset = config_viewpoint_set(session, config)
    return {eid: stored.matches for eid, stored in stored_lists(session, config, vpset.id).items()}


def list_array(matches: Matches, row: int) -> np.ndarray:
    """Row `row` of a search result as a stored-list array, without the empty (-1) slots."""
    keep = matches.shapes[row] >= 0
    return np.stack(
        [matches.shapes[row][keep], matches.views[row][keep], matches.distances[row][keep].astype(np.float64)], axis=1
    ).astype(np.float64).reshape(-1, 3)


def as_matches(arrays: Sequence[np.ndarray], k: int) -> Matches:
    """Stored-list arrays as one `Matches` of width k (missing slots empty)."""
    out = Matches.empty(len(arrays), k)
    for i, arr in enumerate(arrays):
        n = min(len(arr), k)
        out.shapes[i, :n] = arr[:n, 0].astype(np.int64)
        out.views[i, :n] = arr[:n, 1].astype(np.int64)
        out.distances[i, :n] = arr[:n, 2]
    return out


def list_entries(arr: np.ndarray | None) -> set[tuple[int, int, float]]:
    """A stored list as a set of (shape, view, distance), for comparing two versions of it."""
    if arr is None:
        return set()
    return {(int(s), int(v), float(d)) for s, v, d in arr}


def _chunks(items: Sequence[int], size: int = 500) -> list[Sequence[int]]:
    return [items[i : i + size] for i in range(0, len(items), size)]


def write_lists(
    session: Session,
    config: CoarseConfig,
    vp_id: int,
    new_lists: Mapping[int, np.ndarray],
    hashes: Mapping[int, str],
    stored: Mapping[int, StoredList],
    stale: Sequence[int],
    searched_at: dt.datetime,
) -> None:
    """Replace the changed lists' rows, re-stamp the unchanged ones and drop the stale exemplars' rows.

    Called inside one transaction, so an exemplar's list is never seen half written.
    """
    scope = match_scope(config)
    unchanged = [
        eid for eid, arr in new_lists.items()
        if eid in stored and stored[eid].complete and np.array_equal(stored[eid].matches, arr)
    ]
    replaced = sorted(set(new_lists) - set(unchanged))
    for ids in _chunks(sorted({*replaced, *stale})):
        session.execute(
            sa.delete(m.ExemplarMatch).where(*_match_filter(config, vp_id), m.ExemplarMatch.exemplar_id.in_(ids))
        )
    now = utcnow()
    rows = [
        {
            "exemplar_id": eid, "viewpoint_set_id": vp_id, "descriptor": config.hog.name, "scope": scope,
            "rank": rank, "shape_id": int(s), "view_index": int(v), "distance": float(d),
            "searched_at": searched_at, "params_hash": hashes[eid], "created_at": now, "updated_at": now,
        }
        for eid in replaced
        for rank, (s, v, d) in enumerate(new_lists[eid], start=1)
    ]
    if rows:
        session.execute(sa.insert(m.ExemplarMatch.__table__), rows)
    if unchanged:
        table = m.ExemplarMatch.__table__
        session.execute(
            sa.update(table)
            .where(
                table.c.viewpoint_set_id == vp_id, table.c.descriptor == config.hog.name, table.c.scope == scope,
                table.c.exemplar_id == sa.bindparam("eid"),
            )
            .values(searched_at=searched_at, params_hash=sa.bindparam("hash"), updated_at=now),
            [{"eid": eid, "hash": hashes[eid]} for eid in unchanged],
        )
