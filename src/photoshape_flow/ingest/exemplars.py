"""Ingest exemplar photos: decode safely, mask, square-crop, resize, dedupe by dense HOG, write rows.

Items are processed in chunks: (1) each photo is decoded, cleaned and its crop, mask and dense HOG
feature written as blobs; (2) the chunk's features are range-searched (blocked GEMM) against the
index of existing originals and against each other; (3) each exemplar is upserted in its own
transaction, duplicates with `duplicate_of_id` set and `exclude` = true. Natural key: (source,
source_id = path relative to the folder given, without extension; a file given by itself: its stem;
see `photoshape_flow.inputs`); a row stored under a photo's former id (its stem) is renamed, not
duplicated. Replacement of a photo whose file changed deletes its pairs (with their alignments,
substances, assignments, grades, renderings) and its features, and frees the exemplars that were
marked duplicates of it (their flag is cleared, not re-checked).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.hashing import stable_hash
from photoshape_flow.imaging.dedupe import DEFAULT_RADIUS, DESCRIPTOR, assign_duplicates, dense_hog
from photoshape_flow.imaging.exemplar import ExemplarOptions, prepare_exemplar
from photoshape_flow.imaging.io import BadImageError, read_image
from photoshape_flow.ingest.common import (
    FailureWriter,
    IngestLimits,
    IngestSummary,
    Progress,
    adopt_renamed_row,
    existing_row,
    guard_item,
    one_line,
    resolve_settings,
    store_for,
)
from photoshape_flow.inputs import ChangedWhileReadingError, Found, check_unchanged, fingerprint, walk_inputs
from photoshape_flow.store import BlobStore, sha256_file
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, STATUS_REJECTED

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".webp"}
CHUNK = 256


@dataclass
class _Ready:
    """A processed photo waiting for dedupe and its row."""

    path: Path
    row: dict[str, Any]
    feature: np.ndarray
    feature_ref: str
    existing: dict[str, Any] | None


def _existing(url: str, source: str, source_id: str) -> dict[str, Any] | None:
    return existing_row(url, (m.Exemplar.id, m.Exemplar.sha256, m.Exemplar.params_hash, m.Exemplar.status,
                              m.Exemplar.error), m.Exemplar.source == source, m.Exemplar.source_id == source_id)


def delete_exemplar_dependents(session: Session, exemplar_id: int) -> None:
    """Remove rows derived from an exemplar's pixels; free exemplars marked duplicates of it."""
    session.execute(sa.delete(m.Pair).where(m.Pair.exemplar_id == exemplar_id))
    session.execute(sa.delete(m.ExemplarFeature).where(m.ExemplarFeature.exemplar_id == exemplar_id))
    session.execute(sa.delete(m.ExemplarMatch).where(m.ExemplarMatch.exemplar_id == exemplar_id))
    session.execute(
        sa.update(m.Exemplar)
        .where(m.Exemplar.duplicate_of_id == exemplar_id)
        .values(duplicate_of_id=None, exclude=False, exclude_reason=None)
    )


def _load_index(url: str, store: BlobStore, skip_ids: set[int]) -> tuple[np.ndarray, list[int]]:
    """Dedupe features of the existing original (non-duplicate, ok) exemplars."""
    with session_scope(url) as session:
        rows = session.execute(
            sa.select(m.ExemplarFeature.exemplar_id, m.ExemplarFeature.feature_blob)
            .join(m.Exemplar, m.Exemplar.id == m.ExemplarFeature.exemplar_id)
            .where(
                m.ExemplarFeature.descriptor == DESCRIPTOR,
                m.Exemplar.status == STATUS_OK,
                m.Exemplar.duplicate_of_id.is_(None),
            )
        ).all()
    ids: list[int] = []
    feats: list[np.ndarray] = []
    for exemplar_id, ref in rows:
        if exemplar_id in skip_ids or not ref:
            continue
        try:
            feats.append(np.asarray(store.load_array(ref), np.float32))
            ids.append(exemplar_id)
        except (OSError, ValueError) as exc:
            logger.warning("exemplar %d: dedupe feature %s unreadable (%s); not in the index", exemplar_id, ref, exc)
    if not feats:
        return np.zeros((0, 1), np.float32), []
    return np.stack(feats), ids


_record_failure = FailureWriter(
    m.Exemplar, key=("source", "source_id"),
    cleared={"image_blob": None, "mask_blob": None, "size": None, "foreground_fraction": None,
             "duplicate_of_id": None},
    defaults={"meta": {}, "params_hash": ""}, drop_dependents=delete_exemplar_dependents,
)
"""Record a rejected/failed exemplar row (no image, no features) and note it in the summary."""


def _write(url: str, ready: _Ready, duplicate_of: int | None, distance: float | None) -> int:
    values = dict(ready.row)
    values["duplicate_of_id"] = duplicate_of
    values["exclude"] = duplicate_of is not None
    values["exclude_reason"] = (
        f"duplicate of exemplar {duplicate_of} (dense HOG L2 {distance:.3f})" if duplicate_of is not None else None
    )
    with session_scope(url) as session:
        exemplar_id = upsert(session, m.Exemplar, values, key=["source", "source_id"])[0]
        if ready.existing is not None:
            delete_exemplar_dependents(session, exemplar_id)
        upsert(
            session, m.ExemplarFeature,
            {"exemplar_id": exemplar_id, "descriptor": DESCRIPTOR, "feature_blob": ready.feature_ref,
             "dims": int(ready.feature.shape[0]), "status": STATUS_OK, "error": None, "params_hash": ""},
            key=["exemplar_id", "descriptor"],
        )
    return exemplar_id


def ingest_exemplars(
    paths: Iterable[str | Path],
    *,
    source: str | None = None,
    category: str | None = None,
    license: str | None = None,
    attribution: str | None = None,
    source_url: str | None = None,
    size: int = 512,
    dedupe_radius: float = DEFAULT_RADIUS,
    options: ExemplarOptions | None = None,
    settings: Settings | None = None,
    limits: IngestLimits | None = None,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> IngestSummary:
    """Ingest product photos (JPEG/PNG/WebP files or folders of them).

    `size`: side of the stored square crop (the paper used 1000; crops are never upscaled); ignored
    when `options` is given.
    `dedupe_radius`: dense-HOG L2 distance below which a photo is a duplicate.
    """
    settings = resolve_settings(settings)
    url = settings.resolved_database_url
    store = store if store is not None else store_for(settings)
    limits = limits or IngestLimits.from_settings(settings)
    options = options or ExemplarOptions(size=size)
    src = source or "local"
    summary = IngestSummary("exemplars")
    entries = list(walk_inputs(paths, IMAGE_SUFFIXES))
    params_payload = {"options": options.as_dict(), "descriptor": DESCRIPTOR, "version": 1}
    seen: dict[str, Path] = {}
    done = 0
    batch_ids = {f.source_id for f in entries if f.reason is None}
    index, index_ids = _load_index(url, store, _batch_rows(url, src, entries))

    for start in range(0, len(entries), CHUNK):
        ready: list[_Ready] = []
        for found in entries[start : start + CHUNK]:
            done += 1
            path, source_id = found.path, found.source_id
            label = str(path)
            if found.reason is not None:
                summary.reject(label, found.reason)
            elif source_id in seen:
                summary.reject(label, f"source_id {source_id!r} already used by {seen[source_id]} in this batch "
                               "(use --source to tell them apart)")
            else:
                seen[source_id] = path
                item = guard_item(summary, label, lambda found=found: _prepare(
                    found, src, category, license, attribution, source_url, options, limits, params_payload,
                    url, store, summary, batch_ids))
                if isinstance(item, _Ready):
                    ready.append(item)
            if progress is not None:
                progress(label, done, len(entries))
        if not ready:
            continue
        matches = assign_duplicates(np.stack([r.feature for r in ready]), index, dedupe_radius)
        written: list[int] = []
        new_roots: list[tuple[int, np.ndarray]] = []
        for item, match in zip(ready, matches, strict=True):
            duplicate_of = None
            distance = None
            if match is not None:
                duplicate_of = index_ids[match.index] if match.existing else written[match.index]
                distance = match.distance
                if duplicate_of < 0:  # its original could not be written
                    duplicate_of = distance = None
            try:
                exemplar_id = _write(url, item, duplicate_of, distance)
            except Exception as exc:  # database trouble for this item only
                logger.exception("%s: could not write the exemplar row", item.path)
                summary.reject(str(item.path), f"database write failed: {one_line(exc)}")
                written.append(-1)
                continue
            written.append(exemplar_id)
            if duplicate_of is not None:
                summary.duplicates.append((exemplar_id, duplicate_of))
                logger.info("%s: duplicate of exemplar %d (L2 %.3f)", item.path, duplicate_of, distance)
            else:
                new_roots.append((exemplar_id, item.feature))
            was_ok = item.existing is not None and item.existing["status"] == STATUS_OK
            (summary.replaced if was_ok else summary.added).append(exemplar_id)
        if new_roots:
            extra = np.stack([f for _, f in new_roots])
            index = extra if len(index_ids) == 0 else np.concatenate([index, extra])
            index_ids.extend(eid for eid, _ in new_roots)
    logger.info("exemplars: %d added (%d duplicates), %d present, %d replaced, %d rejected", len(summary.added),
                len(summary.duplicates), len(summary.present), len(summary.replaced), len(summary.rejected))
    return summary


def _batch_rows(url: str, source: str, entries: list[Found]) -> set[int]:
    """Rows of this batch's photos (by id, or by former id and path), left out of the dedupe index."""
    usable = [f for f in entries if f.reason is None]
    if not usable:
        return set()
    ids = {f.source_id for f in usable}
    former = {(f.legacy_id, str(f.path.resolve())) for f in usable}
    with session_scope(url) as session:
        rows = session.execute(
            sa.select(m.Exemplar.id, m.Exemplar.source_id, m.Exemplar.source_path)
            .where(m.Exemplar.source == source, m.Exemplar.source_id.in_(ids | {legacy for legacy, _ in former}))
        ).all()
    return {row_id for row_id, sid, path in rows if sid in ids or (sid, path) in former}


def _prepare(
    found: Found, source: str, category: str | None, license: str | None, attribution: str | None,
    source_url: str | None, options: ExemplarOptions, limits: IngestLimits, params_payload: dict[str, Any],
    url: str, store: BlobStore, summary: IngestSummary, batch_ids: set[str],
) -> _Ready | None:
    path, source_id = found.path, found.source_id
    label = str(path)
    existing = _existing(url, source, source_id)
    row: dict[str, Any] = {
        "source": source, "source_id": source_id, "name": path.stem, "category": category,
        "source_path": str(path.resolve()), "license": license, "attribution": attribution,
        "source_url": source_url,
    }
    try:
        before = fingerprint([path])
        sha = sha256_file(path)
    except OSError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, f"unreadable ({exc.strerror or exc})", existing)
        return None
    row["sha256"] = sha
    if existing is None and adopt_renamed_row(url, m.Exemplar, source=source, source_id=source_id,
                                              legacy_id=found.legacy_id, source_path=row["source_path"],
                                              sha256=sha, batch_ids=batch_ids) is not None:
        existing = _existing(url, source, source_id)
    params_hash = stable_hash({"sha256": sha, **params_payload})
    if existing is not None and existing["status"] == STATUS_OK and existing["sha256"] == sha \
            and existing["params_hash"] == params_hash:
        summary.present.append(existing["id"])
        return None
    try:
        rgb, info = read_image(path, max_pixels=limits.max_image_pixels, max_bytes=limits.max_image_bytes,
                               max_aspect=limits.max_exemplar_aspect)
        check_unchanged(before)  # the pixels decoded are the bytes hashed
        prepared = prepare_exemplar(rgb, options)
    except (BadImageError, ChangedWhileReadingError) as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, one_line(exc), existing)
        return None
    except MemoryError:
        _record_failure(url, summary, label, row, STATUS_REJECTED, "out of memory while decoding", existing)
        return None
    except Exception as exc:  # decoder bug or unforeseen input: record, keep going
        logger.debug("%s: unexpected error", label, exc_info=True)
        _record_failure(url, summary, label, row, STATUS_FAILED, f"{type(exc).__name__}: {one_line(exc)}", existing)
        return None
    feature = dense_hog(prepared.image)
    image_ref = store.put_image(prepared.image, "png")
    mask_ref = store.put_image(prepared.mask, "png")
    feature_ref = store.put_array(feature)
    row.update({
        "image_blob": image_ref,
        "mask_blob": mask_ref,
        "native_width": prepared.native_width,
        "native_height": prepared.native_height,
        "size": int(prepared.image.shape[0]),
        "foreground_fraction": prepared.foreground_fraction,
        "meta": {"crop": prepared.crop, "format": info["format"], "has_alpha": info["has_alpha"], **prepared.meta},
        "status": STATUS_OK,
        "error": None,
        "params_hash": params_hash,
    })
    return _Ready(path=path, row=row, feature=feature, feature_ref=feature_ref, existing=existing)
