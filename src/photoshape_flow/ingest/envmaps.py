"""Ingest equirectangular HDR environment maps (.hdr, .exr): validate, store as they are, split.

The file is validated (header size and 2:1 aspect before decoding, then finite, non-negative, not
black) in the isolated worker (decoders are native code), stored byte for byte as a blob, and
given a split: "val" when a hash of its name falls in the lowest 10%, else "train"; after each batch,
when at least two envmaps exist and one split is empty, the envmap with the lowest (for val) or
highest (for train) hash is moved, so training renders and validation renders never share lighting.
`--split` forces the split of the batch; such envmaps are never moved by the balancing.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import sqlalchemy as sa

from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.geometry.isolate import IsolatedWorker, WorkerCrashedError, WorkerTimeoutError
from photoshape_flow.hashing import stable_hash
from photoshape_flow.imaging.hdr import HDR_SUFFIXES, BadEnvmapError, EnvmapLimits, validate_envmap
from photoshape_flow.ingest.common import (
    FailureWriter,
    IngestLimits,
    IngestSummary,
    Progress,
    existing_row,
    guard_item,
    hash_fraction,
    one_line,
    rejection_reason,
    resolve_settings,
    store_for,
)
from photoshape_flow.ingest.materials import materials_without_preview, render_material_previews
from photoshape_flow.inputs import ChangedWhileReadingError, check_unchanged, fingerprint, walk_inputs
from photoshape_flow.store import BlobStore, sha256_file
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, STATUS_REJECTED

logger = logging.getLogger(__name__)

VAL_FRACTION = 0.1


def envmap_split(name: str) -> str:
    return "val" if hash_fraction("envmap", name) < VAL_FRACTION else "train"


def _existing(url: str, name: str) -> dict[str, Any] | None:
    return existing_row(url, (m.Envmap.id, m.Envmap.sha256, m.Envmap.status, m.Envmap.error, m.Envmap.split,
                              m.Envmap.meta), m.Envmap.name == name)


def balance_envmap_splits(url: str) -> list[tuple[str, str]]:
    """Ensure train and val each have an envmap when there are >= 2; returns the (name, split) moves."""
    moves: list[tuple[str, str]] = []
    with session_scope(url) as session:
        rows = session.execute(
            sa.select(m.Envmap.id, m.Envmap.name, m.Envmap.split, m.Envmap.meta)
            .where(m.Envmap.status == STATUS_OK, m.Envmap.enabled)
        ).all()
        if len(rows) < 2:
            return moves
        split_of = {r.id: r.split for r in rows}
        movable = sorted((r for r in rows if (r.meta or {}).get("split_source") != "user"),
                         key=lambda r: hash_fraction("envmap", r.name))
        for wanted in ("val", "train"):
            counts = {s: sum(1 for v in split_of.values() if v == s) for s in ("train", "val")}
            if counts[wanted] > 0:
                continue
            candidates = [r for r in movable if counts.get(split_of[r.id], 0) > 1]
            if not candidates:
                continue
            pick = candidates[0] if wanted == "val" else candidates[-1]
            meta = {**(pick.meta or {}), "split_source": "balance"}
            session.execute(sa.update(m.Envmap).where(m.Envmap.id == pick.id).values(split=wanted, meta=meta))
            split_of[pick.id] = wanted
            moves.append((pick.name, wanted))
            logger.info("envmap %s moved to %s so both splits have lighting", pick.name, wanted)
    return moves


_record_failure = FailureWriter(
    m.Envmap, key=("name",), cleared={"blob": None, "enabled": False}, defaults={"meta": {}},
)
"""Record a rejected/failed envmap row (no blob, disabled) and note it in the summary."""


def _ingest_file(
    path: Path, *, url: str, store: BlobStore, summary: IngestSummary, split: str | None,
    license: str | None, attribution: str | None, source_url: str | None, env_limits: EnvmapLimits,
    worker: IsolatedWorker | None,
) -> None:
    label = str(path)
    name = path.stem
    existing = _existing(url, name)
    wanted_split = split or envmap_split(name)
    if split is None and existing is not None and (existing["meta"] or {}).get("split_source") == "balance":
        wanted_split = existing["split"]  # keep a balanced split stable
    row: dict[str, Any] = {"name": name, "split": wanted_split, "source_path": str(path.resolve()),
                           "license": license, "attribution": attribution, "source_url": source_url}
    try:
        before = fingerprint([path])
        sha = sha256_file(path)
    except OSError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, f"unreadable ({exc.strerror or exc})", existing)
        return
    row["sha256"] = sha
    if existing is not None and existing["status"] == STATUS_OK and existing["sha256"] == sha:
        if split is not None and existing["split"] != split:
            meta = {**(existing["meta"] or {}), "split_source": "user"}
            with session_scope(url) as session:
                session.execute(sa.update(m.Envmap).where(m.Envmap.id == existing["id"]).values(split=split, meta=meta))
        summary.present.append(existing["id"])
        return
    try:
        if worker is not None:
            info = worker.call(validate_envmap, path, env_limits)
        else:
            info = validate_envmap(path, env_limits)
    except BadEnvmapError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, one_line(exc), existing)
        return
    except (WorkerCrashedError, WorkerTimeoutError) as exc:
        _record_failure(url, summary, label, row, STATUS_FAILED, f"decoder {one_line(exc)}", existing)
        return
    except MemoryError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, rejection_reason(exc), existing)
        return
    except Exception as exc:
        logger.debug("%s: unexpected error", label, exc_info=True)
        _record_failure(url, summary, label, row, STATUS_FAILED, f"{type(exc).__name__}: {one_line(exc)}", existing)
        return
    ref = store.put_file(path, ext=path.suffix.lower().lstrip("."))
    try:  # what was validated and stored is what was hashed: the blob's name is its own sha256
        check_unchanged(before)
        if not ref.startswith(sha):
            raise ChangedWhileReadingError(f"{path.name} changed while being read; ingest it again once it is "
                                           "completely written")
    except ChangedWhileReadingError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, one_line(exc), existing)
        return
    values = {
        **row,
        "blob": ref,
        "width": info.width,
        "height": info.height,
        "enabled": True,
        "meta": {"stats": info.stats, "format": path.suffix.lower().lstrip("."),
                 "split_source": "user" if split else "hash",
                 "params_hash": stable_hash({"sha256": sha, "version": 1})},
        "status": STATUS_OK,
        "error": None,
    }
    with session_scope(url) as session:
        envmap_id = upsert(session, m.Envmap, values, key=["name"])[0]
    summary.count_written(label, envmap_id, existing, "envmap")


def ingest_envmaps(
    paths: Iterable[str | Path],
    *,
    split: str | None = None,
    license: str | None = None,
    attribution: str | None = None,
    source_url: str | None = None,
    settings: Settings | None = None,
    limits: IngestLimits | None = None,
    envmap_limits: EnvmapLimits | None = None,
    isolate: bool = True,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> IngestSummary:
    """Ingest .hdr/.exr files or folders of them. `split` forces "train" or "val" for the batch."""
    if split not in (None, "train", "val"):
        raise ValueError(f"split must be 'train' or 'val', got {split!r}")
    settings = resolve_settings(settings)
    url = settings.resolved_database_url
    store = store if store is not None else store_for(settings)
    limits = limits or IngestLimits.from_settings(settings)
    env_limits = envmap_limits or EnvmapLimits()
    summary = IngestSummary("envmaps")
    entries = list(walk_inputs(paths, HDR_SUFFIXES))
    seen: dict[str, Path] = {}
    worker = IsolatedWorker(limits.timeout_s, limits.memory_bytes) if isolate else None
    try:
        for done, found in enumerate(entries, start=1):
            path = found.path
            if found.reason is not None:
                summary.reject(str(path), found.reason)
            elif path.stem in seen:
                summary.reject(str(path), f"envmap name {path.stem!r} already used by {seen[path.stem]} in this batch")
            else:
                seen[path.stem] = path
                guard_item(summary, str(path), lambda path=path: _ingest_file(
                    path, url=url, store=store, summary=summary, split=split, license=license,
                    attribution=attribution, source_url=source_url, env_limits=env_limits, worker=worker))
            if progress is not None:
                progress(str(path), done, len(entries))
    finally:
        if worker is not None:
            worker.close()
    for name, new_split in balance_envmap_splits(url):
        summary.warn(name, f"moved to {new_split} so that train and val both have an envmap")
    logger.info("envmaps: %d added, %d present, %d replaced, %d rejected", len(summary.added),
                len(summary.present), len(summary.replaced), len(summary.rejected))
    if summary.added or summary.replaced:  # materials ingested before any envmap get their previews now

        missing = materials_without_preview(url)
        if missing:
            summary.warnings.extend(render_material_previews(missing, settings=settings, store=store).warnings)
    return summary
