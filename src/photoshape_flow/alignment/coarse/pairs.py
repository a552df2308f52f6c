"""Step 3 of coarse alignment: update the reverse index incrementally and rewrite the affected pairs.

New exemplars (or those whose list hash changed) are searched against every shape; old exemplars
only against the shapes whose features appeared or changed since their ``searched_at``, and the
result is merged into their list. A list whose listed shape vanished or changed, or that lost rows
to a deleted shape's cascade, is searched again in full. The per-exemplar lists are then inverted
into per-shape lists of the top-N exemplars and written as `Pair` rows for the shapes whose
incoming lists changed. Pairs that fall out of a shape's list are excluded (reason
`DROPPED_REASON`), never deleted, because fine alignment, grades and renders hang off them.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.index import Matches, ShardListDatabase, invert, merge_matches
from photoshape_flow.align.retrieval import search
from photoshape_flow.alignment.coarse.config import CoarseConfig
from photoshape_flow.alignment.coarse.reverse_index import (
    StoredList,
    as_matches,
    epoch_seconds,
    list_array,
    list_entries,
    list_hash,
    stored_lists,
    write_lists,
)
from photoshape_flow.alignment.coarse.viewpoint_sets import (
    cameras_hash,
    config_viewpoint_set,
    exemplar_feature_hash,
    view_feature_hash,
)
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.devices import resolve_device, set_torch_threads
from photoshape_flow.hashing import stable_hash
from photoshape_flow.store import BlobStore, default_store

DROPPED_REASON = "coarse-alignment: no longer among the shape's top exemplars"

# per usable shape: (shard ref, when its shard last changed, when it last changed at all)
ShapeStates = dict[int, tuple[str, float, float]]


def pair_hash(config: CoarseConfig, vpset: m.ViewpointSet) -> str:
    """params_hash of the `Pair` rows: every setting the per-shape lists depend on."""
    return stable_hash(
        {
            "k": config.exemplar_topk,
            "mode": config.mode,
            "viewpoints": cameras_hash(vpset),
            "hog": config.hog.params_hash(),
            "top_n": config.shape_topn,
            "max_distance": config.distance_cutoff,
            "category": config.category,
        }
    )


def compute_pairs(*, config: CoarseConfig | None = None, settings: Settings | None = None,
                  store: BlobStore | None = None) -> dict[str, Any]:
    """Update the reverse index with what is new and rewrite the pairs of the affected shapes.

    Returns counts: exemplars searched against all shapes (``full``) or only new shapes
    (``incremental``), shapes whose pairs were rewritten, pairs written and pairs dropped.
    """
    config = config or CoarseConfig()
    settings = settings or get_settings()
    store = store if store is not None else default_store(settings)
    url = settings.resolved_database_url
    start = time.perf_counter()
    scan_time = utcnow()
    with session_scope(url) as session:
        vpset = config_viewpoint_set(session, config)
        vp_id, num_views, cameras = vpset.id, vpset.num_views, np.asarray(vpset.cameras, np.float64)
        current_pair_hash = pair_hash(config, vpset)
        shapes = _usable_shapes(session, config, vpset)
        exemplars = _usable_exemplars(session, config)
        stored = stored_lists(session, config, vp_id)
        active_pairs = _active_pairs(session, config)

    summary: dict[str, Any] = {"shapes": len(shapes), "exemplars": len(exemplars), "full": 0, "incremental": 0}
    k = config.exemplar_topk
    hashes = {eid: list_hash(config, vpset, blob) for eid, blob in exemplars.items()}
    full, by_watermark, old_lists = _plan(shapes, exemplars, stored, hashes, k)

    set_torch_threads(settings.torch_threads)
    search_kw = {"mode": config.mode, "chunk_rows": config.chunk_rows, "query_batch": config.query_batch,
                 "device": resolve_device(settings.device)}

    def db_for(ids: list[int]) -> ShardListDatabase:
        refs = [shapes[s][0] for s in ids]
        return ShardListDatabase(refs, store.load_array, num_views=num_views, dims=config.hog.dims)

    def queries(eids: list[int]) -> np.ndarray:
        return np.stack([store.load_array(exemplars[e]).astype(np.float32).reshape(-1) for e in eids])

    def searched(eids: list[int], shape_ids: list[int]) -> Matches:
        found = search(queries(eids), db_for(shape_ids), k, **search_kw)
        found.shapes = np.where(found.shapes >= 0, np.asarray(shape_ids)[np.maximum(found.shapes, 0)], -1)
        return found

    shape_order = sorted(shapes)
    new_lists: dict[int, np.ndarray] = {}
    if full and shape_order:
        found = searched(full, shape_order)
        for i, eid in enumerate(full):
            new_lists[eid] = list_array(found, i)
    elif full:
        for eid in full:
            new_lists[eid] = np.zeros((0, 3))
    summary["full"] = len(full)
    for watermark, eids in by_watermark.items():
        fresh = [s for s in shape_order if shapes[s][2] > watermark]
        merged = merge_matches(as_matches([old_lists[e] for e in eids], k), searched(eids, fresh), k)
        for i, eid in enumerate(eids):
            new_lists[eid] = list_array(merged, i)
        summary["incremental"] += len(eids)

    stale = sorted(eid for eid in stored if eid not in exemplars)
    affected = _affected_shapes(new_lists, stored, stale, active_pairs, shapes, exemplars, current_pair_hash)
    with session_scope(url) as session:
        write_lists(session, config, vp_id, new_lists, hashes, stored, stale, scan_time)

    written = dropped = 0
    if affected:
        empty = np.zeros((0, 3))
        eids = sorted(exemplars)
        lists = as_matches([new_lists.get(e, old_lists.get(e, empty)) for e in eids], k)
        per_shape = invert(eids, lists, config.shape_topn, config.distance_cutoff)
        written, dropped = _write_pairs(url, sorted(affected), per_shape, cameras, vp_id, config, current_pair_hash)
    summary.update(
        shapes_affected=len(affected), pairs_written=written, pairs_dropped=dropped,
        seconds=round(time.perf_counter() - start, 3),
    )
    return summary


def _usable_shapes(session: Session, config: CoarseConfig, vpset: m.ViewpointSet) -> ShapeStates:
    """Per usable shape: (shard ref, when its shard last changed, when the shape last changed at all).

    The latter also catches a shape that comes back (un-excluded), whose shard is old. Shapes whose
    shard is stale are left out: they wait for step 1.
    """
    shape_q = (
        sa.select(
            m.ViewFeature.shape_id, m.ViewFeature.feature_blob, m.ViewFeature.updated_at,
            m.ViewFeature.params_hash, m.Shape.mesh_blob, m.Shape.updated_at,
        )
        .join(m.Shape, m.Shape.id == m.ViewFeature.shape_id)
        .where(
            m.ViewFeature.viewpoint_set_id == vpset.id, m.ViewFeature.descriptor == config.hog.name,
            m.ViewFeature.status == "ok", m.ViewFeature.feature_blob.is_not(None),
            m.Shape.status == "ok", ~m.Shape.exclude,
        )
    )
    if config.category is not None:
        shape_q = shape_q.where(m.Shape.category == config.category)
    shapes: ShapeStates = {}
    for sid, blob, updated, h, mesh_blob, shape_updated in session.execute(shape_q.order_by(m.ViewFeature.shape_id)):
        if h == view_feature_hash(config, vpset, mesh_blob):
            shapes[sid] = (blob, epoch_seconds(updated), max(epoch_seconds(updated), epoch_seconds(shape_updated)))
    return shapes


def _usable_exemplars(session: Session, config: CoarseConfig) -> dict[int, str]:
    """exemplar id -> feature ref, for ok, included, non-duplicate exemplars with an up-to-date feature."""
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
    return {
        eid: blob
        for eid, blob, h, img, msk in session.execute(ex_q.order_by(m.ExemplarFeature.exemplar_id))
        if h == exemplar_feature_hash(config, img, msk)
    }


def _active_pairs(session: Session, config: CoarseConfig) -> list[Any]:
    """(shape id, exemplar id, params_hash) of the pairs not excluded, in the configured category."""
    pair_q = (
        sa.select(m.Pair.shape_id, m.Pair.exemplar_id, m.Pair.params_hash)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .where(~m.Pair.exclude)
    )
    if config.category is not None:  # other categories' pairs are another run's business
        pair_q = pair_q.where(m.Shape.category == config.category)
    return list(session.execute(pair_q).all())


def _plan(
    shapes: ShapeStates, exemplars: Mapping[int, str], stored: Mapping[int, StoredList], hashes: Mapping[int, str],
    k: int,
) -> tuple[list[int], dict[float, list[int]], dict[int, np.ndarray]]:
    """Which exemplars to search in full, which only against shapes newer than their list (grouped by
    the list's ``searched_at``), and the still valid stored lists of the latter."""
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
    return full, by_watermark, old_lists


def _affected_shapes(
    new_lists: Mapping[int, np.ndarray],
    stored: Mapping[int, StoredList],
    stale: list[int],
    active_pairs: list[Any],
    shapes: ShapeStates,
    exemplars: Mapping[int, str],
    current_pair_hash: str,
) -> set[int]:
    """Shapes whose incoming exemplar entries changed, or whose pairs are out of date."""
    affected: set[int] = set()
    for eid, arr in new_lists.items():
        previous = stored[eid].matches if eid in stored else None
        affected.update(s for s, _, _ in list_entries(previous) ^ list_entries(arr))
    for eid in stale:
        affected.update(int(s) for s in stored[eid].matches[:, 0])
    for sid, eid, h in active_pairs:
        if sid not in shapes or eid not in exemplars or h != current_pair_hash:
            affected.add(int(sid))
    return affected


def _write_pairs(
    url: str,
    shape_ids: list[int],
    per_shape: Mapping[int, list[Any]],
    cameras: np.ndarray,
    vp_id: int,
    config: CoarseConfig,
    params_hash: str,
) -> tuple[int, int]:
    """Upsert each shape's listed pairs (ranked) and exclude the ones that fell out of its list."""
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
                    "elevation": el, "fov": fov, "camera_distance": dist, "params_hash": params_hash,
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
