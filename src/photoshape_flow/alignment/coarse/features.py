"""Steps 1 and 2 of coarse alignment: the descriptor shards of shapes and of exemplars.

Step 1 renders each usable shape's viewpoint sweep and stores one float16 (views x dims) shard as
a `ViewFeature` row; step 2 stores the same descriptor of each exemplar's crop and mask as an
`ExemplarFeature` row. An item is skipped when its row is ok with the expected params_hash; an
item that fails gets a ``failed`` row with a one-line error, the batch goes on, and the item is
retried on the next run.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import sqlalchemy as sa

from photoshape_flow.align.descriptors import exemplar_descriptor, render_view_descriptors
from photoshape_flow.align.viewpoints import cameras_from_rows
from photoshape_flow.alignment.coarse.config import CoarseConfig
from photoshape_flow.alignment.coarse.viewpoint_sets import (
    config_viewpoint_set,
    exemplar_feature_hash,
    view_feature_hash,
)
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.pipeline.errors import error_line
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store

log = logging.getLogger(__name__)


def compute_view_features(
    shape_ids: Sequence[int] | None = None,
    *,
    config: CoarseConfig | None = None,
    settings: Settings | None = None,
    renderer: RendererProtocol | None = None,
    limit: int | None = None,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> dict[str, Any]:
    """Descriptor shards of the viewpoint sweep of each pending shape (all usable shapes by default).

    Returns counts: computed, skipped (up to date), failed, plus seconds and the errors by shape id.
    """
    start = time.perf_counter()
    config, store, url = _step_inputs(config, settings, store)
    with session_scope(url) as session:
        vpset = config_viewpoint_set(session, config)
        vp_id, cameras = vpset.id, cameras_from_rows(vpset.cameras)
        q = sa.select(m.Shape.id, m.Shape.mesh_blob).where(
            m.Shape.status == "ok", ~m.Shape.exclude, m.Shape.mesh_blob.is_not(None)
        )
        shapes = session.execute(_restricted(q, m.Shape, shape_ids, config.category)).all()
        existing = _feature_states(
            session,
            sa.select(m.ViewFeature.shape_id, m.ViewFeature.params_hash, m.ViewFeature.status).where(
                m.ViewFeature.viewpoint_set_id == vp_id, m.ViewFeature.descriptor == config.hog.name
            ),
        )
        expected = {sid: view_feature_hash(config, vpset, blob) for sid, blob in shapes}
    pending = _pending(shapes, existing, expected, limit)
    if pending and renderer is None:
        renderer = default_renderer(store)
    def shard(item: Sequence[Any]) -> dict[str, Any]:
        item_start = time.perf_counter()
        mesh = ShapeMesh.from_npz_bytes(store.read_bytes(item[1]))
        feats = _finite(render_view_descriptors(renderer, mesh, cameras, config.hog))
        return {
            "feature_blob": store.put_array(feats.astype(np.float16)), "dims": int(feats.shape[1]),
            "num_views": int(feats.shape[0]),
            "meta": {"seconds": round(time.perf_counter() - item_start, 3), "hog": config.hog.to_dict()},
        }

    summary = _store_each(
        pending,
        key=lambda item: {"shape_id": item[0], "viewpoint_set_id": vp_id, "descriptor": config.hog.name,
                          "params_hash": expected[item[0]]},
        compute=shard,
        failed={"feature_blob": None, "dims": None, "num_views": None, "meta": {}},
        model=m.ViewFeature,
        conflict=["shape_id", "viewpoint_set_id", "descriptor"],
        url=url,
        what=("shape", "view features"),
        progress=progress,
    )
    summary["skipped"] = len(shapes) - len(pending)
    summary["seconds"] = round(time.perf_counter() - start, 3)
    return summary


def compute_exemplar_features(
    exemplar_ids: Sequence[int] | None = None,
    *,
    config: CoarseConfig | None = None,
    settings: Settings | None = None,
    limit: int | None = None,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> dict[str, Any]:
    """The descriptor of each pending exemplar from its stored crop and mask (same counts as above)."""
    start = time.perf_counter()
    config, store, url = _step_inputs(config, settings, store)
    with session_scope(url) as session:
        q = sa.select(m.Exemplar.id, m.Exemplar.image_blob, m.Exemplar.mask_blob).where(
            m.Exemplar.status == "ok", ~m.Exemplar.exclude, m.Exemplar.image_blob.is_not(None)
        )
        exemplars = session.execute(_restricted(q, m.Exemplar, exemplar_ids, config.category)).all()
        existing = _feature_states(
            session,
            sa.select(m.ExemplarFeature.exemplar_id, m.ExemplarFeature.params_hash, m.ExemplarFeature.status).where(
                m.ExemplarFeature.descriptor == config.hog.name
            ),
        )
    expected = {eid: exemplar_feature_hash(config, img, msk) for eid, img, msk in exemplars}
    pending = _pending(exemplars, existing, expected, limit)

    def descriptor(item: Sequence[Any]) -> dict[str, Any]:
        _, image_blob, mask_blob = item
        if mask_blob is None:
            raise ValueError("exemplar has no mask_blob")
        feat = _finite(exemplar_descriptor(store.load_image(image_blob), store.load_image(mask_blob), config.hog))
        return {"feature_blob": store.put_array(feat.astype(np.float16)), "dims": int(feat.size)}

    summary = _store_each(
        pending,
        key=lambda item: {"exemplar_id": item[0], "descriptor": config.hog.name, "params_hash": expected[item[0]]},
        compute=descriptor,
        failed={"feature_blob": None, "dims": None},
        model=m.ExemplarFeature,
        conflict=["exemplar_id", "descriptor"],
        url=url,
        what=("exemplar", "features"),
        progress=progress,
    )
    summary["skipped"] = len(exemplars) - len(pending)
    summary["seconds"] = round(time.perf_counter() - start, 3)
    return summary


def _step_inputs(config: CoarseConfig | None, settings: Settings | None,
                 store: BlobStore | None) -> tuple[CoarseConfig, BlobStore, str]:
    """A step's configuration and blob store (the defaults when None) and database URL."""
    settings = settings or get_settings()
    store = store if store is not None else default_store(settings)
    return config or CoarseConfig(), store, settings.resolved_database_url


def _restricted(query: sa.Select[Any], model: Any, ids: Sequence[int] | None, category: str | None) -> sa.Select[Any]:
    """`query` limited to `ids` (when given) and to one category (when configured), in id order."""
    if ids is not None:
        query = query.where(model.id.in_(list(ids)))
    if category is not None:
        query = query.where(model.category == category)
    return query.order_by(model.id)


def _feature_states(session: Any, query: sa.Select[Any]) -> dict[int, tuple[str, str]]:
    """item id -> (params_hash, status) of its stored feature row."""
    return {item_id: (h, status) for item_id, h, status in session.execute(query)}


def _pending(
    items: Sequence[Sequence[Any]], existing: Mapping[int, tuple[str, str]], expected: Mapping[int, str],
    limit: int | None,
) -> list[Sequence[Any]]:
    """The items (rows starting with their id) without an ok feature of the expected hash, at most `limit`."""
    pending = [item for item in items if existing.get(item[0]) != (expected[item[0]], "ok")]
    return pending if limit is None else pending[:limit]


def _finite(values: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(values)):
        raise ValueError("non-finite descriptor values")
    return values


def _store_each(
    pending: Sequence[Sequence[Any]],
    *,
    key: Callable[[Sequence[Any]], dict[str, Any]],
    compute: Callable[[Sequence[Any]], dict[str, Any]],
    failed: Mapping[str, Any],
    model: Any,
    conflict: list[str],
    url: str,
    what: tuple[str, str],
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Compute and upsert one feature row per item, each in its own transaction.

    `key` gives a row's identity and params_hash, `compute` its ok columns; an exception stores the
    `failed` columns with the error instead, so one item's failure never stops the batch. `conflict`
    names the row's unique columns, `what` the item and the feature for the log (and the progress task).
    """
    summary: dict[str, Any] = {"computed": 0, "skipped": 0, "failed": 0, "errors": {}}
    for item in counted(progress, f"coarse-alignment {what[0]} {what[1]}", pending):
        row = key(item)
        try:
            row.update(compute(item), status="ok", error=None)
            summary["computed"] += 1
        except Exception as exc:  # one item's failure must not stop the batch
            log.warning("%s %s: %s failed: %s", what[0], item[0], what[1], error_line(exc))
            row.update(failed, status="failed", error=error_line(exc))
            summary["failed"] += 1
            summary["errors"][item[0]] = row["error"]
        with session_scope(url) as session:
            upsert(session, model, row, key=conflict)
    return summary
