"""Ingest 3D shapes: discover, read + preprocess in an isolated worker, store the mesh, write rows.

Per shape, in one transaction: the `shape` row (natural key source + source_id) and its `part`
rows (one per material group, numbered from 1). The preprocessed `ShapeMesh` is stored as an .npz
blob (`shape.mesh_blob`), built-in textures as image blobs referenced from `part.builtin_material`.

Replacement: when a shape's source files change (content hash), its row is updated in place (same
id) and everything derived from the old geometry is deleted in the same transaction: parts (and
through them part substances and assignments), pairs (and their alignments, grades, renderings),
view features and renderings of the shape. `params_hash` covers the content hash and the
preprocessing options, so a changed preprocessing version re-ingests as well.

Ids: plain files are keyed by their path relative to the folder given (`photoshape_flow.inputs`);
a row stored under a file's former id (its stem) is renamed to the new id before anything else
(`adopt_renamed_row`, by recorded path, then by content), so an old data root is updated in place.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.faults import fault_point
from photoshape_flow.geometry.isolate import IsolatedWorker, WorkerCrashedError, WorkerTimeoutError
from photoshape_flow.geometry.prepare import TEXTURE_PLACEHOLDER, PreparedShape, prepare_shape
from photoshape_flow.geometry.preprocess import PreprocessOptions
from photoshape_flow.geometry.raw import BadShapeError
from photoshape_flow.geometry.sources import RejectedInput, ShapeItem, discover_shapes, materialize
from photoshape_flow.hashing import stable_hash
from photoshape_flow.ingest.common import (
    FailureWriter,
    IngestLimits,
    IngestSummary,
    Progress,
    adopt_renamed_row,
    existing_row,
    guard_item,
    one_line,
    rejection_reason,
    resolve_settings,
    split_for,
    store_for,
)
from photoshape_flow.inputs import ChangedWhileReadingError, check_unchanged
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, STATUS_REJECTED

logger = logging.getLogger(__name__)


def _existing(url: str, source: str, source_id: str) -> dict[str, Any] | None:
    return existing_row(url, (m.Shape.id, m.Shape.sha256, m.Shape.params_hash, m.Shape.status, m.Shape.error,
                              m.Shape.split), m.Shape.source == source, m.Shape.source_id == source_id)


def delete_shape_dependents(session: Session, shape_id: int) -> None:
    """Remove every row derived from a shape's geometry (its parts included)."""
    session.execute(sa.delete(m.Pair).where(m.Pair.shape_id == shape_id))
    session.execute(sa.delete(m.ViewFeature).where(m.ViewFeature.shape_id == shape_id))
    session.execute(sa.delete(m.Rendering).where(m.Rendering.shape_id == shape_id))
    part_ids = sa.select(m.Part.id).where(m.Part.shape_id == shape_id)
    session.execute(sa.delete(m.PartSubstance).where(m.PartSubstance.part_id.in_(part_ids)))
    session.execute(sa.delete(m.Assignment).where(m.Assignment.part_id.in_(part_ids)))
    session.execute(sa.delete(m.Part).where(m.Part.shape_id == shape_id))


def _source_path(item: ShapeItem) -> str:
    if item.archive is not None:
        return f"{item.archive.resolve()}!{item.member}"
    assert item.file is not None
    return str(item.file.resolve())


def _base_row(item: ShapeItem, split: str) -> dict[str, Any]:
    return {
        "source": item.source,
        "source_id": item.source_id,
        "name": item.name,
        "category": item.category,
        "split": split,
        "source_path": _source_path(item),
        "license": item.license,
        "attribution": item.attribution,
        "source_url": item.source_url,
    }


_record_failure = FailureWriter(
    m.Shape, key=("source", "source_id"),
    cleared={"mesh_blob": None, "num_vertices": None, "num_faces": None, "num_parts": None},
    defaults={"meta": {}, "params_hash": ""}, drop_dependents=delete_shape_dependents,
)
"""Record a rejected/failed shape row (no mesh, no parts) and note it in the summary."""


def _store_prepared(store: BlobStore, prepared: PreparedShape) -> str:
    refs = {key: store.put_bytes(data, ext) for key, (data, ext) in prepared.textures.items()}
    for part in prepared.mesh.parts:
        texture = part.builtin_material.get("texture")
        if isinstance(texture, str) and texture.startswith(TEXTURE_PLACEHOLDER):
            if texture in refs:
                part.builtin_material["texture"] = refs[texture]
            else:
                part.builtin_material.pop("texture")
    return store.put_bytes(prepared.mesh.to_npz_bytes(), "npz")


def _part_rows(shape_id: int, prepared: PreparedShape) -> list[dict[str, Any]]:
    rows = []
    for part in prepared.mesh.parts:
        rows.append({
            "shape_id": shape_id,
            "index": part.index,
            "name": part.name,
            "num_faces": int(len(part.faces)),
            "area_world": part.area_world,
            "area_uv": part.area_uv,
            "uv_density": part.uv_density,
            "builtin_material": part.builtin_material,
            "meta": part.meta,
        })
    return rows


def _ingest_item(
    item: ShapeItem, *, url: str, store: BlobStore, summary: IngestSummary, split: str | None,
    limits: IngestLimits, options: PreprocessOptions, worker: IsolatedWorker | None, batch_ids: set[str],
) -> None:
    label = item.label
    existing = _existing(url, item.source, item.source_id)

    def adopt(sha256: str | None) -> dict[str, Any] | None:
        """The row this file had under its former id (by path, then by content), renamed to its id."""
        found = adopt_renamed_row(url, m.Shape, source=item.source, source_id=item.source_id,
                                  legacy_id=item.legacy_id, source_path=_source_path(item), sha256=sha256,
                                  batch_ids=batch_ids)
        return None if found is None else _existing(url, item.source, item.source_id)

    if existing is None:
        existing = adopt(None)
    wanted_split = split or split_for(item.source, item.source_id)
    row = _base_row(item, wanted_split)
    if item.size_bytes > limits.max_shape_bytes:
        _record_failure(url, summary, label, row, STATUS_REJECTED,
                        f"file is {item.size_bytes} bytes (limit {limits.max_shape_bytes})", existing)
        return
    item_options = dataclasses.replace(options, rotation=item.rotation) if item.rotation else options
    try:
        with materialize(item, limits.archive) as files:
            row["sha256"] = files.sha256
            if existing is None:
                existing = adopt(files.sha256)
            params_hash = stable_hash({"sha256": files.sha256, "preprocess": item_options.as_dict(),
                                       "rotation": item.rotation})
            if (
                existing is not None and existing["status"] == STATUS_OK
                and existing["sha256"] == files.sha256 and existing["params_hash"] == params_hash
            ):
                if split is not None and existing["split"] != split:
                    with session_scope(url) as session:
                        session.execute(sa.update(m.Shape).where(m.Shape.id == existing["id"]).values(split=split))
                summary.present.append(existing["id"])
                return
            args = (str(files.model), item.fmt, str(files.root), item_options, limits.max_faces,
                    limits.max_texture_pixels)
            if worker is not None:
                prepared = worker.call(prepare_shape, *args)
            else:
                prepared = prepare_shape(*args)
            check_unchanged(files.fingerprints)  # the mesh read is the bytes hashed
    except (BadShapeError, ChangedWhileReadingError) as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, one_line(exc), existing)
        return
    except (WorkerCrashedError, WorkerTimeoutError) as exc:
        _record_failure(url, summary, label, row, STATUS_FAILED, f"importer {one_line(exc)}", existing)
        return
    except MemoryError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, rejection_reason(exc), existing)
        return
    except OSError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, f"unreadable ({one_line(exc)})", existing)
        return
    except Exception as exc:  # a bug or an unforeseen library error: record, keep going
        logger.debug("%s: unexpected error", label, exc_info=True)
        _record_failure(url, summary, label, row, STATUS_FAILED, f"{type(exc).__name__}: {one_line(exc)}", existing)
        return
    for warning in prepared.warnings:
        summary.warn(label, warning)
    mesh_ref = _store_prepared(store, prepared)
    fault_point("ingest-blob-before-row")
    mesh = prepared.mesh
    meta = {**mesh.meta, **item.meta, "split_source": "user" if split else "hash"}
    values = {
        **row,
        "params_hash": params_hash,
        "mesh_blob": mesh_ref,
        "num_vertices": mesh.num_vertices,
        "num_faces": mesh.num_faces,
        "num_parts": len(mesh.parts),
        "meta": meta,
        "status": STATUS_OK,
        "error": None,
    }
    try:
        with session_scope(url) as session:  # one transaction: the shape and its parts, or neither
            shape_id = upsert(session, m.Shape, values, key=["source", "source_id"])[0]
            if existing is not None:
                delete_shape_dependents(session, shape_id)
            session.execute(sa.insert(m.Part), _part_rows(shape_id, prepared))
    except Exception as exc:  # a row the database refuses (a bug upstream): this shape fails, the batch goes on
        logger.exception("%s: could not store the shape", label)
        _record_failure(url, summary, label, row, STATUS_FAILED,
                        f"could not store it: {type(exc).__name__}: {one_line(exc).splitlines()[0][:300]}", existing)
        return
    summary.count_written(label, shape_id, existing, "shape")


def _record_rejected(
    url: str, summary: IngestSummary, item: RejectedInput, *, split: str | None, license: str | None,
    attribution: str | None,
) -> None:
    """A refused input's line, and its `rejected` row when it has a key.

    Run behind `guard_item` like any other item: a row the database refuses costs this line, never
    the batch (a catalog piece's id may hold a ``\\uD800`` escape that no text column stores).
    """
    if not (item.source and item.source_id):
        summary.reject(item.label, item.reason)
        return
    row = {"source": item.source, "source_id": item.source_id, "name": item.name,
           "split": split or split_for(item.source, item.source_id), "source_path": item.label,
           "license": license, "attribution": attribution, "sha256": None}
    _record_failure(url, summary, item.label, row, STATUS_REJECTED, item.reason,
                    _existing(url, item.source, item.source_id))


def ingest_shapes(
    paths: Iterable[str | Path],
    *,
    source: str | None = None,
    category: str | None = None,
    name_filter: str | None = None,
    split: str | None = None,
    license: str | None = None,
    attribution: str | None = None,
    settings: Settings | None = None,
    limits: IngestLimits | None = None,
    options: PreprocessOptions | None = None,
    isolate: bool = True,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> IngestSummary:
    """Ingest OBJ/glTF/GLB files, ShapeNetCore v2 trees and Sweet Home 3D catalogs.

    `category`: for ShapeNet and catalogs a filter (comma-separated), for plain files the category
    to record. `name_filter`: regular expression on names/ids/tags. `split`: force "train"/"val"
    (default: deterministic 90/10 from a hash of source and source_id). `isolate`: parse and
    preprocess in a child process so a crashing native library costs one item.
    """
    settings = resolve_settings(settings)
    if split not in (None, "train", "val"):
        raise ValueError(f"split must be 'train' or 'val', got {split!r}")
    url = settings.resolved_database_url
    store = store if store is not None else store_for(settings)
    limits = limits or IngestLimits.from_settings(settings)
    options = options or PreprocessOptions()
    summary = IngestSummary("shapes")
    items = discover_shapes(paths, source=source, category=category, name_filter=name_filter,
                            license=license, attribution=attribution, archive_limits=limits.archive)
    seen: dict[tuple[str, str], str] = {}
    batch_ids = {item.source_id for item in items if isinstance(item, ShapeItem)}
    worker = IsolatedWorker(limits.timeout_s, limits.memory_bytes) if isolate else None
    try:
        for done, item in enumerate(items, start=1):
            if isinstance(item, RejectedInput):
                guard_item(summary, item.label, lambda item=item: _record_rejected(
                    url, summary, item, split=split, license=license, attribution=attribution))
            else:
                key = (item.source, item.source_id)
                if key in seen:
                    summary.reject(item.label, f"source_id {item.source_id!r} already used by {seen[key]} in this "
                                   "batch (use --source to tell them apart)")
                else:
                    seen[key] = item.label
                    guard_item(summary, item.label, lambda item=item: _ingest_item(
                        item, url=url, store=store, summary=summary, split=split, limits=limits, options=options,
                        worker=worker, batch_ids=batch_ids))
            if progress is not None:
                progress(item.label, done, len(items))
    finally:
        if worker is not None:
            worker.close()
    logger.info("shapes: %d added, %d present, %d replaced, %d rejected", len(summary.added),
                len(summary.present), len(summary.replaced), len(summary.rejected))
    return summary
