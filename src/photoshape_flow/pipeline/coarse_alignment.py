"""Coarse alignment stage (section 4.1): viewpoint sets, descriptors, the reverse index, pairs.

Three steps, each idempotent and incremental:

1. `compute_view_features`: per shape, render the shaded viewpoint sweep and store one float16
   (views x dims) shard as a `ViewFeature` row; skipped when a row with the same params_hash exists.
2. `compute_exemplar_features`: per exemplar, the same descriptor from the stored crop and mask.
3. `compute_pairs`: the reverse index (per exemplar: the top-k shapes, best view each) by exact
   search, inverted into per-shape lists of the top-N exemplars, written as `Pair` rows.

The reverse index is persisted as `ExemplarMatch` rows, one per (exemplar, viewpoint set,
descriptor, scope, rank) where scope is the category restriction or ''. Each row holds the shape,
its best view and the squared distance, plus ``searched_at``, when that exemplar's list was last
searched, and ``params_hash`` over k, mode, viewpoints, descriptor settings, the exemplar's feature
and the category. A later run therefore searches new exemplars (or those whose hash changed)
against every shape but old exemplars only against the shapes whose features appeared or changed
since their ``searched_at``, merges, and rewrites the pairs of the shapes whose exemplar lists
changed. A list whose listed shape vanished or changed, or that lost rows to a deleted shape's
cascade, is searched again in full. An exemplar's rows are replaced in one transaction (unchanged
lists only get a new ``searched_at``). Pairs that fall out of a shape's list are excluded (reason
`DROPPED_REASON`), never deleted, because fine alignment, grades and renders hang off them.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import logging
import math
import time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.descriptors import (
    CALIBRATED_MAX_DISTANCE,
    HogParams,
    crop_mask,
    exemplar_descriptor,
    render_view_descriptors,
)
from photoshape_flow.align.retrieval import Matches, ShardListDatabase, invert, merge_matches, search
from photoshape_flow.align.viewpoints import (
    NAMED_VIEWPOINT_SETS,
    ViewpointParams,
    angular_errors_deg,
    cameras_from_rows,
    viewpoint_array,
)
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.store import BlobStore

log = logging.getLogger(__name__)

STAGE = "coarse-alignment"
DROPPED_REASON = "coarse-alignment: no longer among the shape's top exemplars"


@dataclass(frozen=True)
class CoarseConfig:
    """Parameters of the coarse alignment stage."""

    viewpoint_set: str = "paper-456"
    viewpoint_version: int = 1
    viewpoint_params: ViewpointParams | None = None  # None: the named set's parameters
    hog: HogParams = field(default_factory=HogParams)
    exemplar_topk: int = 8  # shapes per exemplar in the reverse index (the original kept 8)
    shape_topn: int = 12  # exemplars per shape (paper, section 6: top 12)
    # drop pairs farther than this (squared L2); None: the channel set's calibrated cut-off
    # (descriptors.CALIBRATED_MAX_DISTANCE), or keep all if it has none; math.inf keeps all
    max_distance: float | None = None
    mode: str = "exact"  # or "bf16" (see align.retrieval)
    chunk_rows: int = 16384
    query_batch: int = 2048
    category: str | None = None  # restrict shapes and exemplars to one category

    def with_hog(self, **changes: Any) -> CoarseConfig:
        return replace(self, hog=replace(self.hog, **changes))

    @property
    def distance_cutoff(self) -> float | None:
        if self.max_distance is not None:
            return None if math.isinf(self.max_distance) else float(self.max_distance)
        return CALIBRATED_MAX_DISTANCE.get(self.hog.channels)


def _hash(payload: Any) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def _settings(settings: Settings | None) -> Settings:
    return settings or get_settings()


def _one_line(exc: BaseException) -> str:
    text = f"{type(exc).__name__}: {exc}".splitlines()
    return text[0][:500] if text else type(exc).__name__


def _ts(value: dt.datetime | None) -> float:
    """Seconds since the epoch; naive values (SQLite) are UTC."""
    if value is None:
        return float("-inf")
    if value.tzinfo is None:
        value = value.replace(tzinfo=dt.UTC)
    return value.timestamp()


# -- viewpoint sets -------------------------------------------------------------------------------
def ensure_viewpoint_set(
    session: Session, name: str = "paper-456", version: int = 1, params: ViewpointParams | None = None
) -> m.ViewpointSet:
    """The `ViewpointSet` row (name, version), created from `params` (default: the named set's).

    A set is immutable: asking for an existing (name, version) with other cameras is an error, so a
    changed sweep needs a new version and both can coexist.
    """
    if params is None:
        if name not in NAMED_VIEWPOINT_SETS:
            raise ValueError(f"unknown viewpoint set {name!r}: pass params (known: {sorted(NAMED_VIEWPOINT_SETS)})")
        params = NAMED_VIEWPOINT_SETS[name]
    cameras = viewpoint_array(params)
    existing = session.execute(
        sa.select(m.ViewpointSet).where(m.ViewpointSet.name == name, m.ViewpointSet.version == version)
    ).scalar_one_or_none()
    if existing is not None:
        stored = np.asarray(existing.cameras, np.float64)
        if stored.shape != cameras.shape or not np.allclose(stored, cameras, atol=1e-9):
            raise ValueError(
                f"viewpoint set {name} v{version} exists with other cameras ({stored.shape[0]} views); "
                "use a new version"
            )
        return existing
    upsert(
        session,
        m.ViewpointSet,
        {
            "name": name,
            "version": version,
            "num_views": int(len(cameras)),
            "cameras": cameras.tolist(),
            "params": params.to_dict(),
        },
        key=["name", "version"],
        update=[],
    )
    return session.execute(
        sa.select(m.ViewpointSet).where(m.ViewpointSet.name == name, m.ViewpointSet.version == version)
    ).scalar_one()


def _viewpoint_set(session: Session, config: CoarseConfig) -> m.ViewpointSet:
    return ensure_viewpoint_set(session, config.viewpoint_set, config.viewpoint_version, config.viewpoint_params)


def _cameras_hash(vpset: m.ViewpointSet) -> str:
    return _hash(np.round(np.asarray(vpset.cameras, np.float64), 9).tolist())


def view_feature_hash(config: CoarseConfig, vpset: m.ViewpointSet, mesh_blob: str | None) -> str:
    return config.hog.params_hash(mesh=mesh_blob, viewpoints=_cameras_hash(vpset))


def exemplar_feature_hash(config: CoarseConfig, image_blob: str | None, mask_blob: str | None) -> str:
    return config.hog.params_hash(image=image_blob, mask=mask_blob)


# -- step 1: view features ------------------------------------------------------------------------
def compute_view_features(
    shape_ids: Sequence[int] | None = None,
    *,
    config: CoarseConfig | None = None,
    settings: Settings | None = None,
    renderer: Any = None,
    limit: int | None = None,
) -> dict[str, Any]:
    """Descriptor shards of the viewpoint sweep of each pending shape (all usable shapes by default).

    Returns counts: computed, skipped (up to date), failed, plus seconds. A shape that fails gets a
    ``failed`` row with a one-line error and the batch goes on; failed shapes are retried next run.
    """
    config = config or CoarseConfig()
    settings = _settings(settings)
    store = BlobStore(settings.blob_root)
    url = settings.resolved_database_url
    start = time.perf_counter()
    with session_scope(url) as session:
        vpset = _viewpoint_set(session, config)
        vp_id, cameras = vpset.id, cameras_from_rows(vpset.cameras)
        q = sa.select(m.Shape.id, m.Shape.mesh_blob).where(
            m.Shape.status == "ok", ~m.Shape.exclude, m.Shape.mesh_blob.is_not(None)
        )
        if shape_ids is not None:
            q = q.where(m.Shape.id.in_(list(shape_ids)))
        if config.category is not None:
            q = q.where(m.Shape.category == config.category)
        shapes = session.execute(q.order_by(m.Shape.id)).all()
        existing = {
            sid: (h, status)
            for sid, h, status in session.execute(
                sa.select(m.ViewFeature.shape_id, m.ViewFeature.params_hash, m.ViewFeature.status).where(
                    m.ViewFeature.viewpoint_set_id == vp_id, m.ViewFeature.descriptor == config.hog.name
                )
            )
        }
        expected = {sid: view_feature_hash(config, vpset, blob) for sid, blob in shapes}
    pending = [(sid, blob) for sid, blob in shapes if existing.get(sid) != (expected[sid], "ok")]
    if limit is not None:
        pending = pending[:limit]
    summary: dict[str, Any] = {"computed": 0, "skipped": len(shapes) - len(pending), "failed": 0, "errors": {}}
    if pending and renderer is None:
        from photoshape_flow.render import renderer as render_module

        renderer = render_module.Renderer()
    from photoshape_flow.geometry.mesh import ShapeMesh

    for sid, blob in pending:
        row: dict[str, Any] = {
            "shape_id": sid,
            "viewpoint_set_id": vp_id,
            "descriptor": config.hog.name,
            "params_hash": expected[sid],
        }
        try:
            item_start = time.perf_counter()
            mesh = ShapeMesh.from_npz_bytes(store.read_bytes(blob))
            feats = render_view_descriptors(renderer, mesh, cameras, config.hog)
            if not np.all(np.isfinite(feats)):
                raise ValueError("non-finite descriptor values")
            ref = store.put_array(feats.astype(np.float16))
            row.update(
                feature_blob=ref, dims=int(feats.shape[1]), num_views=int(feats.shape[0]), status="ok", error=None,
                meta={"seconds": round(time.perf_counter() - item_start, 3), "hog": config.hog.to_dict()},
            )
            summary["computed"] += 1
        except Exception as exc:  # one shape's failure must not stop the batch
            log.warning("shape %s: view features failed: %s", sid, _one_line(exc))
            row.update(feature_blob=None, dims=None, num_views=None, status="failed", error=_one_line(exc), meta={})
            summary["failed"] += 1
            summary["errors"][sid] = row["error"]
        with session_scope(url) as session:
            upsert(session, m.ViewFeature, row, key=["shape_id", "viewpoint_set_id", "descriptor"])
    summary["seconds"] = round(time.perf_counter() - start, 3)
    return summary


# -- step 2: exemplar features --------------------------------------------------------------------
def compute_exemplar_features(
    exemplar_ids: Sequence[int] | None = None,
    *,
    config: CoarseConfig | None = None,
    settings: Settings | None = None,
    limit: int | None = None,
) -> dict[str, Any]:
    """The descriptor of each pending exemplar from its stored crop and mask (same counts as above)."""
    config = config or CoarseConfig()
    settings = _settings(settings)
    store = BlobStore(settings.blob_root)
    url = settings.resolved_database_url
    start = time.perf_counter()
    with session_scope(url) as session:
        q = sa.select(m.Exemplar.id, m.Exemplar.image_blob, m.Exemplar.mask_blob).where(
            m.Exemplar.status == "ok", ~m.Exemplar.exclude, m.Exemplar.image_blob.is_not(None)
        )
        if exemplar_ids is not None:
            q = q.where(m.Exemplar.id.in_(list(exemplar_ids)))
        if config.category is not None:
            q = q.where(m.Exemplar.category == config.category)
        exemplars = session.execute(q.order_by(m.Exemplar.id)).all()
        existing = {
            eid: (h, status)
            for eid, h, status in session.execute(
                sa.select(m.ExemplarFeature.exemplar_id, m.ExemplarFeature.params_hash, m.ExemplarFeature.status).where(
                    m.ExemplarFeature.descriptor == config.hog.name
                )
            )
        }
    expected = {eid: exemplar_feature_hash(config, img, msk) for eid, img, msk in exemplars}
    pending = [e for e in exemplars if existing.get(e[0]) != (expected[e[0]], "ok")]
    if limit is not None:
        pending = pending[:limit]
    summary: dict[str, Any] = {"computed": 0, "skipped": len(exemplars) - len(pending), "failed": 0, "errors": {}}
    for eid, image_blob, mask_blob in pending:
        row: dict[str, Any] = {"exemplar_id": eid, "descriptor": config.hog.name, "params_hash": expected[eid]}
        try:
            if mask_blob is None:
                raise ValueError("exemplar has no mask_blob")
            feat = exemplar_descriptor(store.load_image(image_blob), store.load_image(mask_blob), config.hog)
            if not np.all(np.isfinite(feat)):
                raise ValueError("non-finite descriptor values")
            ref = store.put_array(feat.astype(np.float16))
            row.update(feature_blob=ref, dims=int(feat.size), status="ok", error=None)
            summary["computed"] += 1
        except Exception as exc:  # one exemplar's failure must not stop the batch
            log.warning("exemplar %s: features failed: %s", eid, _one_line(exc))
            row.update(feature_blob=None, dims=None, status="failed", error=_one_line(exc))
            summary["failed"] += 1
            summary["errors"][eid] = row["error"]
        with session_scope(url) as session:
            upsert(session, m.ExemplarFeature, row, key=["exemplar_id", "descriptor"])
    summary["seconds"] = round(time.perf_counter() - start, 3)
    return summary


# -- step 3: reverse index and pairs --------------------------------------------------------------
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


def _state_hash(config: CoarseConfig, vpset: m.ViewpointSet, feature_blob: str) -> str:
    return _hash(
        {
            "k": config.exemplar_topk,
            "mode": config.mode,
            "viewpoints": _cameras_hash(vpset),
            "hog": config.hog.params_hash(),
            "feature": feature_blob,
            "category": config.category,
        }
    )


def _pair_hash(config: CoarseConfig, vpset: m.ViewpointSet) -> str:
    return _hash(
        {
            "k": config.exemplar_topk,
            "mode": config.mode,
            "viewpoints": _cameras_hash(vpset),
            "hog": config.hog.params_hash(),
            "top_n": config.shape_topn,
            "max_distance": config.distance_cutoff,
            "category": config.category,
        }
    )


@dataclass(frozen=True)
class _StoredList:
    """One exemplar's stored top-k list: (n, 3) [shape id, view index, squared distance], nearest first."""

    matches: np.ndarray
    params_hash: str | None  # None: the rows disagree
    searched_at: float  # seconds since the epoch
    complete: bool  # ranks are 1..n (no row lost to a deleted shape's cascade) and hashes agree


def _stored_lists(session: Session, config: CoarseConfig, viewpoint_set_id: int) -> dict[int, _StoredList]:
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
    out: dict[int, _StoredList] = {}
    for eid, entries in grouped.items():
        hashes = {r.params_hash for r in entries}
        params_hash = next(iter(hashes)) if len(hashes) == 1 else None
        out[eid] = _StoredList(
            matches=np.array([[r.shape_id, r.view_index, r.distance] for r in entries], np.float64).reshape(-1, 3),
            params_hash=params_hash,
            searched_at=min(_ts(r.searched_at) for r in entries),
            complete=params_hash is not None and [r.rank for r in entries] == list(range(1, len(entries) + 1)),
        )
    return out


def _state_array(matches: Matches, row: int) -> np.ndarray:
    keep = matches.shapes[row] >= 0
    return np.stack(
        [matches.shapes[row][keep], matches.views[row][keep], matches.distances[row][keep].astype(np.float64)], axis=1
    ).astype(np.float64).reshape(-1, 3)


def _as_matches(arrays: Sequence[np.ndarray], k: int) -> Matches:
    out = Matches.empty(len(arrays), k)
    for i, arr in enumerate(arrays):
        n = min(len(arr), k)
        out.shapes[i, :n] = arr[:n, 0].astype(np.int64)
        out.views[i, :n] = arr[:n, 1].astype(np.int64)
        out.distances[i, :n] = arr[:n, 2]
    return out


def _entries(arr: np.ndarray | None) -> set[tuple[int, int, float]]:
    if arr is None:
        return set()
    return {(int(s), int(v), float(d)) for s, v, d in arr}


def _chunks(items: Sequence[int], size: int = 500) -> list[Sequence[int]]:
    return [items[i : i + size] for i in range(0, len(items), size)]


def _write_lists(
    session: Session,
    config: CoarseConfig,
    vp_id: int,
    new_lists: Mapping[int, np.ndarray],
    hashes: Mapping[int, str],
    stored: Mapping[int, _StoredList],
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


def compute_pairs(*, config: CoarseConfig | None = None, settings: Settings | None = None) -> dict[str, Any]:
    """Update the reverse index with what is new and rewrite the pairs of the affected shapes.

    Returns counts: exemplars searched against all shapes (``full``) or only new shapes
    (``incremental``), shapes whose pairs were rewritten, pairs written and pairs dropped.
    """
    config = config or CoarseConfig()
    settings = _settings(settings)
    store = BlobStore(settings.blob_root)
    url = settings.resolved_database_url
    start = time.perf_counter()
    scan_time = utcnow()
    with session_scope(url) as session:
        vpset = _viewpoint_set(session, config)
        vp_id, num_views, cameras = vpset.id, vpset.num_views, np.asarray(vpset.cameras, np.float64)
        pair_hash = _pair_hash(config, vpset)

        shape_q = (
            sa.select(
                m.ViewFeature.shape_id, m.ViewFeature.feature_blob, m.ViewFeature.updated_at,
                m.ViewFeature.params_hash, m.Shape.mesh_blob, m.Shape.updated_at,
            )
            .join(m.Shape, m.Shape.id == m.ViewFeature.shape_id)
            .where(
                m.ViewFeature.viewpoint_set_id == vp_id, m.ViewFeature.descriptor == config.hog.name,
                m.ViewFeature.status == "ok", m.ViewFeature.feature_blob.is_not(None),
                m.Shape.status == "ok", ~m.Shape.exclude,
            )
        )
        if config.category is not None:
            shape_q = shape_q.where(m.Shape.category == config.category)
        # per usable shape: (shard ref, when its shard last changed, when it last changed at all); the
        # latter also catches a shape that comes back (un-excluded), whose shard is old
        shapes: dict[int, tuple[str, float, float]] = {}
        for sid, blob, updated, h, mesh_blob, shape_updated in session.execute(
            shape_q.order_by(m.ViewFeature.shape_id)
        ):
            if h == view_feature_hash(config, vpset, mesh_blob):  # stale shards wait for step 1
                shapes[sid] = (blob, _ts(updated), max(_ts(updated), _ts(shape_updated)))

        ex_q = (
            sa.select(
                m.ExemplarFeature.exemplar_id, m.ExemplarFeature.feature_blob, m.ExemplarFeature.params_hash,
                m.Exemplar.image_blob, m.Exemplar.mask_blob,
            )
            .join(m.Exemplar, m.Exemplar.id == m.ExemplarFeature.exemplar_id)
            .where(
                m.ExemplarFeature.descriptor == config.hog.name, m.ExemplarFeature.status == "ok",
                m.ExemplarFeature.feature_blob.is_not(None),
                m.Exemplar.status == "ok", ~m.Exemplar.exclude, m.Exemplar.duplicate_of_id.is_(None),
            )
        )
        if config.category is not None:
            ex_q = ex_q.where(m.Exemplar.category == config.category)
        exemplars: dict[int, str] = {
            eid: blob
            for eid, blob, h, img, msk in session.execute(ex_q.order_by(m.ExemplarFeature.exemplar_id))
            if h == exemplar_feature_hash(config, img, msk)
        }
        stored = _stored_lists(session, config, vp_id)
        pair_q = (
            sa.select(m.Pair.shape_id, m.Pair.exemplar_id, m.Pair.params_hash)
            .join(m.Shape, m.Shape.id == m.Pair.shape_id)
            .where(~m.Pair.exclude)
        )
        if config.category is not None:  # other categories' pairs are another run's business
            pair_q = pair_q.where(m.Shape.category == config.category)
        active_pairs = session.execute(pair_q).all()

    summary: dict[str, Any] = {"shapes": len(shapes), "exemplars": len(exemplars), "full": 0, "incremental": 0}
    k = config.exemplar_topk
    hashes = {eid: _state_hash(config, vpset, blob) for eid, blob in exemplars.items()}
    old_lists: dict[int, np.ndarray] = {}
    full: list[int] = []
    by_watermark: dict[float, list[int]] = defaultdict(list)
    newest_shape = max((seen for _, _, seen in shapes.values()), default=float("-inf"))
    for eid in exemplars:
        state = stored.get(eid)
        if state is None or not state.complete or state.params_hash != hashes[eid]:
            if state is not None or shapes:  # with no shapes there is nothing to search yet
                full.append(eid)
            continue
        arr = state.matches
        old_lists[eid] = arr
        listed = {int(s) for s in arr[:, 0]}
        # a listed shape that vanished or whose shard changed invalidates the list: another shape
        # beyond the old k-th may now belong in it; so does a short list that misses a shape it
        # should have seen (its row went with a deleted shape)
        if any(s not in shapes or shapes[s][1] > state.searched_at for s in listed) or (
            len(arr) < k and any(s not in listed and seen <= state.searched_at for s, (_, _, seen) in shapes.items())
        ):
            full.append(eid)
        elif newest_shape > state.searched_at:
            by_watermark[state.searched_at].append(eid)

    shape_order = sorted(shapes)
    new_lists: dict[int, np.ndarray] = {}

    def db_for(ids: list[int]) -> ShardListDatabase:
        refs = [shapes[s][0] for s in ids]
        return ShardListDatabase(refs, store.load_array, num_views=num_views, dims=config.hog.dims)

    def queries(eids: list[int]) -> np.ndarray:
        return np.stack([store.load_array(exemplars[e]).astype(np.float32).reshape(-1) for e in eids])

    search_kw = {"mode": config.mode, "chunk_rows": config.chunk_rows, "query_batch": config.query_batch,
                 "device": _device(settings)}
    if full and shape_order:
        found = search(queries(full), db_for(shape_order), k, **search_kw)
        found.shapes = np.where(found.shapes >= 0, np.asarray(shape_order)[np.maximum(found.shapes, 0)], -1)
        for i, eid in enumerate(full):
            new_lists[eid] = _state_array(found, i)
    elif full:
        for eid in full:
            new_lists[eid] = np.zeros((0, 3))
    summary["full"] = len(full)
    for watermark, eids in by_watermark.items():
        fresh = [s for s in shape_order if shapes[s][2] > watermark]
        found = search(queries(eids), db_for(fresh), k, **search_kw)
        found.shapes = np.where(found.shapes >= 0, np.asarray(fresh)[np.maximum(found.shapes, 0)], -1)
        merged = merge_matches(_as_matches([old_lists[e] for e in eids], k), found, k)
        for i, eid in enumerate(eids):
            new_lists[eid] = _state_array(merged, i)
        summary["incremental"] += len(eids)

    # shapes whose incoming exemplar entries changed
    affected: set[int] = set()
    for eid, arr in new_lists.items():
        previous = stored[eid].matches if eid in stored else None
        affected.update(s for s, _, _ in _entries(previous) ^ _entries(arr))
    stale = sorted(eid for eid in stored if eid not in exemplars)
    for eid in stale:
        affected.update(int(s) for s in stored[eid].matches[:, 0])
    for sid, eid, h in active_pairs:
        if sid not in shapes or eid not in exemplars or h != pair_hash:
            affected.add(int(sid))

    with session_scope(url) as session:
        _write_lists(session, config, vp_id, new_lists, hashes, stored, stale, scan_time)

    written = dropped = 0
    if affected:
        empty = np.zeros((0, 3))
        eids = sorted(exemplars)
        lists = _as_matches([new_lists.get(e, old_lists.get(e, empty)) for e in eids], k)
        per_shape = invert(eids, lists, config.shape_topn, config.distance_cutoff)
        written, dropped = _write_pairs(url, sorted(affected), per_shape, cameras, vp_id, config, pair_hash)
    summary.update(
        shapes_affected=len(affected), pairs_written=written, pairs_dropped=dropped,
        seconds=round(time.perf_counter() - start, 3),
    )
    return summary


def _device(settings: Settings) -> str:
    import torch

    if settings.torch_threads > 0:
        torch.set_num_threads(settings.torch_threads)
    if settings.device == "cpu":
        return "cpu"
    return "cuda" if torch.cuda.is_available() else "cpu"


def _write_pairs(
    url: str,
    shape_ids: list[int],
    per_shape: Mapping[int, list[Any]],
    cameras: np.ndarray,
    vp_id: int,
    config: CoarseConfig,
    pair_hash: str,
) -> tuple[int, int]:
    written = dropped = 0
    with session_scope(url) as session:
        existing: dict[tuple[int, int], tuple[bool, str | None]] = {
            (sid, eid): (excl, reason)
            for sid, eid, excl, reason in session.execute(
                sa.select(m.Pair.shape_id, m.Pair.exemplar_id, m.Pair.exclude, m.Pair.exclude_reason).where(
                    m.Pair.shape_id.in_(shape_ids)
                )
            )
        }
        for sid in shape_ids:
            keep = set()
            for rank, entry in enumerate(per_shape.get(sid, []), start=1):
                az, el, dist, fov = (float(x) for x in cameras[entry.view])
                row = {
                    "shape_id": sid, "exemplar_id": entry.exemplar, "viewpoint_set_id": vp_id,
                    "descriptor": config.hog.name, "view_index": entry.view, "rank": rank,
                    "exemplar_rank": entry.exemplar_rank, "distance": entry.distance, "azimuth": az,
                    "elevation": el, "fov": fov, "camera_distance": dist, "params_hash": pair_hash,
                    "params": {"mode": config.mode, "exemplar_topk": config.exemplar_topk,
                               "shape_topn": config.shape_topn, "max_distance": config.distance_cutoff},
                }
                prior = existing.get((sid, entry.exemplar))
                if prior is None or not prior[0] or prior[1] == DROPPED_REASON:
                    row.update(exclude=False, exclude_reason=None)  # a curator's exclusion stays
                upsert(session, m.Pair, row, key=["shape_id", "exemplar_id"])
                keep.add(entry.exemplar)
                written += 1
            for (psid, eid), (excl, _) in existing.items():
                if psid == sid and eid not in keep and not excl:
                    session.execute(
                        sa.update(m.Pair)
                        .where(m.Pair.shape_id == sid, m.Pair.exemplar_id == eid)
                        .values(exclude=True, exclude_reason=DROPPED_REASON, updated_at=utcnow())
                    )
                    dropped += 1
    return written, dropped


# -- the whole stage ------------------------------------------------------------------------------
def run_coarse_alignment(
    settings: Settings | None = None,
    batch: int | None = None,
    *,
    config: CoarseConfig | None = None,
    renderer: Any = None,
) -> dict[str, Any]:
    """Features of up to `batch` pending shapes and exemplars (all when None), then the pairs."""
    config = config or CoarseConfig()
    settings = _settings(settings)
    start = time.perf_counter()
    summary = {
        "view_features": compute_view_features(config=config, settings=settings, renderer=renderer, limit=batch),
        "exemplar_features": compute_exemplar_features(config=config, settings=settings, limit=batch),
        "pairs": compute_pairs(config=config, settings=settings),
    }
    summary["seconds"] = round(time.perf_counter() - start, 3)
    log.info("coarse alignment: %s", summary)
    return summary


# -- evaluation against ground truth --------------------------------------------------------------
def load_reverse_index(session: Session, config: CoarseConfig | None = None) -> dict[int, np.ndarray]:
    """Per exemplar id: its (n, 3) [shape id, view index, distance] list, nearest first."""
    config = config or CoarseConfig()
    vpset = _viewpoint_set(session, config)
    return {eid: stored.matches for eid, stored in _stored_lists(session, config, vpset.id).items()}


def _gt_entries(groundtruth: Any) -> dict[str, dict[str, Any]]:
    """Exemplar stem -> {"shape", "in_collection", "camera"} from a `demo.groundtruth.GroundTruth`
    (or anything with an ``exemplars`` mapping of such records) or from plain dicts."""
    exemplars = getattr(groundtruth, "exemplars", groundtruth)
    out: dict[str, dict[str, Any]] = {}
    for stem, entry in exemplars.items():
        if isinstance(entry, Mapping):
            out[str(stem)] = dict(entry)
            continue
        camera = getattr(entry, "camera", None)
        out[str(stem)] = {
            "shape": getattr(entry, "shape", None),
            "in_collection": getattr(entry, "in_collection", None),
            "camera": None if camera is None else {"azimuth": camera.azimuth, "elevation": camera.elevation},
        }
    return out


def _gt_get(entry: Mapping[str, Any], *names: str) -> Any:
    for name in names:
        if name in entry and entry[name] is not None:
            return entry[name]
    return None


def evaluate_coarse_alignment(
    session: Session,
    groundtruth: Any,
    *,
    config: CoarseConfig | None = None,
    renderer: Any = None,
    iou_size: int = 128,
) -> dict[str, float]:
    """Shape recall, pose error and silhouette IoU of the reverse index against demo ground truth.

    `groundtruth` is the demo's `GroundTruth` (``demo.groundtruth.load_groundtruth``) or a mapping from
    an exemplar's file stem (its ``source_id``, or that path's stem) to a dict with the true shape's
    ``shape``/``shape_source_id``, ``in_collection`` and ``camera`` (azimuth and elevation, radians).
    Shape recall@1/@5 counts exemplars whose shape is in the collection;
    the pose error is measured at the true shape's entry when it was retrieved (median degrees,
    azimuth wrapped); the silhouette IoU renders the top-1 shape's part IDs at the retrieved camera,
    crops it like the exemplar and compares it with the exemplar's mask (``iou_nearest``: exemplars
    whose shape is not in the collection, ``iou_in_collection``: the others).
    """
    config = config or CoarseConfig()
    store = BlobStore(get_settings().blob_root)
    vpset = _viewpoint_set(session, config)
    cameras = cameras_from_rows(vpset.cameras)
    index = load_reverse_index(session, config)
    exemplars = session.execute(sa.select(m.Exemplar.id, m.Exemplar.source_id, m.Exemplar.mask_blob)).all()
    by_stem: dict[str, tuple[int, str | None]] = {}
    for eid, source_id, mask_blob in exemplars:
        for key in {source_id, source_id.rsplit("/", 1)[-1], source_id.rsplit("/", 1)[-1].rsplit(".", 1)[0]}:
            by_stem.setdefault(key, (eid, mask_blob))
    shape_ids = {src: sid for sid, src in session.execute(sa.select(m.Shape.id, m.Shape.source_id))}
    meshes = dict(session.execute(sa.select(m.Shape.id, m.Shape.mesh_blob)).all())

    hits = {1: 0, 5: 0}
    n_in = 0
    az_err: list[float] = []
    el_err: list[float] = []
    iou: dict[bool, list[float]] = {True: [], False: []}
    mesh_cache: dict[int, Any] = {}
    for stem, truth in _gt_entries(groundtruth).items():
        found = by_stem.get(stem)
        if found is None or found[0] not in index:
            continue
        eid, mask_blob = found
        listed = index[eid]
        retrieved = [int(s) for s in listed[:, 0]]
        true_sid = shape_ids.get(str(_gt_get(truth, "shape_source_id", "shape", "shape_id")))
        in_collection = bool(_gt_get(truth, "in_collection")) if "in_collection" in truth else true_sid is not None
        in_collection = in_collection and true_sid is not None
        if in_collection:
            n_in += 1
            for k in hits:
                hits[k] += int(true_sid in retrieved[:k])
            camera = _gt_get(truth, "camera")
            if true_sid in retrieved and camera is not None:
                view = int(listed[retrieved.index(true_sid), 1])
                daz, del_ = angular_errors_deg(
                    cameras[view].azimuth, cameras[view].elevation, float(camera["azimuth"]), float(camera["elevation"])
                )
                az_err.append(float(daz))
                el_err.append(float(del_))
        if len(retrieved) and mask_blob is not None and meshes.get(retrieved[0]):
            if renderer is None:
                from photoshape_flow.render import renderer as render_module

                renderer = render_module.Renderer()
            from photoshape_flow.geometry.mesh import ShapeMesh

            sid = retrieved[0]
            if sid not in mesh_cache:
                mesh_cache[sid] = ShapeMesh.from_npz_bytes(store.read_bytes(meshes[sid]))
            ids = renderer.part_ids(mesh_cache[sid], cameras[int(listed[0, 1])], size=2 * iou_size)
            ours = crop_mask(ids > 0, iou_size)
            theirs = crop_mask(store.load_image(mask_blob), iou_size)
            union = np.logical_or(ours, theirs).sum()
            iou[in_collection].append(float(np.logical_and(ours, theirs).sum() / union) if union else 0.0)

    def median(values: list[float]) -> float:
        return float(np.median(values)) if values else float("nan")

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else float("nan")

    return {
        "recall@1": hits[1] / n_in if n_in else float("nan"),
        "recall@5": hits[5] / n_in if n_in else float("nan"),
        "n_in_collection": float(n_in),
        "median_azimuth_error_deg": median(az_err),
        "median_elevation_error_deg": median(el_err),
        "n_pose": float(len(az_err)),
        "mean_iou_nearest": mean(iou[False]),
        "median_iou_nearest": median(iou[False]),
        "n_nearest": float(len(iou[False])),
        "mean_iou_in_collection": mean(iou[True]),
    }
