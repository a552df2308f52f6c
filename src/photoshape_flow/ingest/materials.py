"""Ingest materials: SVBRDF folders (maps recognised by name + sidecar) and analytic sidecars.

Each folder becomes one `material` row (natural key: name). Maps are converted to the contract's
channels (gloss -> roughness, DirectX -> OpenGL normals, packed ARM unpacked) and stored as PNG
blobs; `material.maps` maps channel -> ref. Without a metallic map, `params.metallic` is 1 for the
metal substance and 0 otherwise; without a roughness map `params.roughness` defaults to 0.5.
A changed folder (content hash of its maps and sidecar) updates the row in place and bumps its
`params_hash` (and clears its preview), which invalidates renderings and classifiers built on it.

After a batch that added materials is committed, one Prefect event `photoshape.material.added`
is emitted (only when a Prefect API is configured). Previews (a sphere under an envmap) are
rendered by `render_material_previews` when the Mitsuba renderer is available.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.events import EventSink
from photoshape_flow.export.text import one_line as text_line
from photoshape_flow.geometry.primitives import uv_sphere
from photoshape_flow.hashing import stable_hash
from photoshape_flow.imaging.svbrdf import (
    SIDECARS,
    BadMaterialError,
    is_material_folder,
    load_maps,
    scan_material,
)
from photoshape_flow.ingest.common import (
    FailureWriter,
    IngestLimits,
    IngestSummary,
    Progress,
    existing_row,
    files_hash,
    guard_item,
    one_line,
    resolve_settings,
    store_for,
)
from photoshape_flow.inputs import ChangedWhileReadingError, check_unchanged, fingerprint, link_refusal
from photoshape_flow.render import Camera, EnvmapSpec, MaterialSpec
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, STATUS_REJECTED

logger = logging.getLogger(__name__)

MAX_DEPTH = 4


def discover_material_folders(paths: Iterable[str | Path]) -> list[tuple[Path, str | None]]:
    """Material folders under the given paths: (folder, None), or (path, reason) for bad paths."""
    out: list[tuple[Path, str | None]] = []
    for given in paths:
        path = Path(given)
        if not path.exists():
            out.append((path, "no such file or folder"))
            continue
        if path.is_file():
            if path.name in SIDECARS:
                out.append((path.parent, None))
            else:
                out.append((path, "expected a material folder (maps + material.json) or a folder of them"))
            continue
        if is_material_folder(path):
            out.append((path, None))
            continue
        found: list[Path] = []
        refused: list[tuple[Path, str | None]] = []
        frontier = [path]
        for _ in range(MAX_DEPTH):
            children = sorted(c for d in frontier for c in d.iterdir() if c.is_dir() and not c.name.startswith("."))
            frontier = []
            for child in children:
                link = link_refusal(child, path)
                if link is not None:
                    refused.append((child, link))
                else:
                    (found if is_material_folder(child) else frontier).append(child)
        if not found and not refused:
            out.append((path, "no material folders found (no recognised maps or material.json)"))
        out.extend(sorted([*((f, None) for f in found), *refused], key=lambda item: item[0]))
    return out


def _existing(url: str, name: str) -> dict[str, Any] | None:
    return existing_row(url, (m.Material.id, m.Material.sha256, m.Material.params_hash, m.Material.status,
                              m.Material.error, m.Material.source_path), m.Material.name == name)


_write_failure = FailureWriter(
    m.Material, key=("name",), cleared={"maps": {}, "preview_blob": None, "enabled": False},
    defaults={"substance": "unknown", "meta": {}, "params": {}, "params_hash": ""},
)


def _record_failure(
    url: str, summary: IngestSummary, label: str, row: dict[str, Any], status: str, reason: str,
    existing: dict[str, Any] | None,
) -> None:
    """Record a rejected/failed material row (no maps, disabled) and note it in the summary.

    Never over another folder's good material: the key is a name, which a folder's own name or its
    sidecar gives, so a poison sidecar in a folder called `oak` would otherwise wipe the maps of the
    `oak` another folder holds. Then the reason is one line only, and the good row stays.
    """
    if existing is not None and existing["status"] == STATUS_OK and existing["source_path"] != row["source_path"]:
        summary.reject(label, f"{reason} (material {row['name']!r} from {existing['source_path']} is kept)")
        return
    _write_failure(url, summary, label, row, status, reason, existing)


def _store_map(store, channel: str, array: np.ndarray) -> str:  # type: ignore[no-untyped-def]
    return store.put_image(np.ascontiguousarray(array), "png")


def ingest_materials(
    paths: Iterable[str | Path],
    *,
    substance: str | None = None,
    source: str | None = None,
    license: str | None = None,
    attribution: str | None = None,
    previews: bool = True,
    preview_size: int = 128,
    settings: Settings | None = None,
    limits: IngestLimits | None = None,
    progress: Progress | None = None,
    events: EventSink | None = None,
    store: BlobStore | None = None,
    renderer: RendererProtocol | None = None,
) -> IngestSummary:
    """Ingest material folders; `summary.new_material_ids` lists the materials this call added.

    `events` (the CLI's and the flows' Prefect sink) is told of the new materials once they are
    committed, before previews render, so a re-run can be triggered as early as possible.
    """
    settings = resolve_settings(settings)
    url = settings.resolved_database_url
    store = store if store is not None else store_for(settings)
    limits = limits or IngestLimits.from_settings(settings)
    summary = IngestSummary("materials")
    folders = discover_material_folders(paths)
    seen: dict[str, Path] = {}
    for done, (folder, reason) in enumerate(folders, start=1):
        label = str(folder)
        if reason is not None:
            summary.reject(label, reason)
        else:
            guard_item(summary, label, lambda folder=folder: _ingest_folder(
                folder, url=url, store=store, summary=summary, substance=substance, source=source,
                license=license, attribution=attribution, limits=limits, seen=seen))
        if progress is not None:
            progress(label, done, len(folders))
    if events is not None and summary.new_material_ids:
        summary.announced = bool(events.materials_added(summary.new_material_ids))
    # previews for this batch, and for materials still without one (e.g. ingested before any envmap)
    pending = (summary.added + summary.replaced
               + [i for i in materials_without_preview(url) if i in summary.present]) if previews else []
    if pending:
        preview = render_material_previews(pending, settings=settings, size=preview_size, store=store,
                                           renderer=renderer)
        summary.skipped.extend(preview.skipped)
        summary.warnings.extend(preview.warnings)
    logger.info("materials: %d added, %d present, %d replaced, %d rejected", len(summary.added),
                len(summary.present), len(summary.replaced), len(summary.rejected))
    return summary


def _ingest_folder(
    folder: Path, *, url: str, store, summary: IngestSummary, substance: str | None,  # type: ignore[no-untyped-def]
    source: str | None, license: str | None, attribution: str | None, limits: IngestLimits,
    seen: dict[str, Path],
) -> None:
    label = str(folder)
    try:
        scan = scan_material(folder, substance=substance, source=source, license=license, attribution=attribution)
    except BadMaterialError as exc:
        name = text_line(folder.name)  # the rejected row's key: one safe line, whatever the folder is called
        _record_failure(url, summary, label, {"name": name, "source_path": str(folder.resolve()),
                                              "substance": (substance or "unknown")[:32]},
                        STATUS_REJECTED, one_line(exc), _existing(url, name))
        return
    except OSError as exc:
        summary.reject(label, f"unreadable ({exc.strerror or exc})")
        return
    if scan.name in seen:
        summary.reject(label, f"material name {scan.name!r} already used by {seen[scan.name]} in this batch")
        return
    seen[scan.name] = folder
    for warning in scan.warnings:
        summary.warn(label, warning)
    existing = _existing(url, scan.name)
    row: dict[str, Any] = {
        "name": scan.name,
        "substance": scan.substance,
        "kind": scan.kind,
        "default_scale": scan.scale,
        "source": scan.provenance["source"],
        "license": scan.provenance["license"],
        "attribution": scan.provenance["attribution"],
        "source_url": scan.provenance["source_url"],
        "source_path": str(folder.resolve()),
    }
    try:
        before = fingerprint(scan.hashed_files())
        sha = files_hash(scan.hashed_files(), base=folder)
    except OSError as exc:
        _record_failure(url, summary, label, row, STATUS_REJECTED, f"unreadable ({exc.strerror or exc})", existing)
        return
    row["sha256"] = sha
    params_hash = stable_hash({"sha256": sha, "version": 1, "substance": scan.substance, "scale": scan.scale})
    if existing is not None and existing["status"] == STATUS_OK and existing["sha256"] == sha \
            and existing["params_hash"] == params_hash:
        summary.present.append(existing["id"])
        return
    params = dict(scan.params)
    maps: dict[str, str] = {}
    meta: dict[str, Any] = {}
    if scan.kind == "svbrdf":
        known_warnings = len(scan.warnings)
        try:
            arrays, meta = load_maps(scan, max_pixels=limits.max_image_pixels, max_bytes=limits.max_image_bytes)
            check_unchanged(before)  # the maps decoded are the bytes hashed
        except (BadMaterialError, ChangedWhileReadingError) as exc:
            _record_failure(url, summary, label, row, STATUS_REJECTED, one_line(exc), existing)
            return
        except Exception as exc:  # decoder trouble: record, keep going
            logger.debug("%s: unexpected error", label, exc_info=True)
            _record_failure(url, summary, label, row, STATUS_FAILED, f"{type(exc).__name__}: {one_line(exc)}",
                            existing)
            return
        for warning in scan.warnings[known_warnings:]:
            summary.warn(label, warning)
        maps = {channel: _store_map(store, channel, array) for channel, array in arrays.items()}
        if "metallic" not in maps:
            params.setdefault("metallic", 1.0 if scan.substance == "metal" else 0.0)
        if "roughness" not in maps:
            params.setdefault("roughness", 0.5)
    if scan.warnings:
        meta["warnings"] = list(scan.warnings)
    values = {
        **row,
        "maps": maps,
        "params": params,
        "meta": meta,
        "preview_blob": None,
        "enabled": True,
        "status": STATUS_OK,
        "error": None,
        "params_hash": params_hash,
    }
    with session_scope(url) as session:
        material_id = upsert(session, m.Material, values, key=["name"])[0]
    summary.count_written(label, material_id, existing, "material")


def materials_without_preview(url: str) -> list[int]:
    """Ids of usable materials that have no preview render yet."""
    with session_scope(url) as session:
        return list(session.execute(
            sa.select(m.Material.id).where(m.Material.status == STATUS_OK, m.Material.preview_blob.is_(None))
            .order_by(m.Material.id)
        ).scalars())


def render_material_previews(
    material_ids: Iterable[int],
    *,
    settings: Settings | None = None,
    size: int = 128,
    spp: int = 32,
    store: BlobStore | None = None,
    renderer: RendererProtocol | None = None,
) -> IngestSummary:
    """Render a sphere preview per material into `material.preview_blob`.

    Skips, with a logged reason in `summary.skipped`, when the renderer cannot be imported or
    started (no Mitsuba / LLVM) or no envmap is ingested; a failing material is a warning.
    `summary.added` lists the materials that got a preview.
    """
    settings = resolve_settings(settings)
    summary = IngestSummary("previews")
    ids = list(material_ids)
    if not ids:
        return summary
    url = settings.resolved_database_url
    store = store if store is not None else store_for(settings)
    with session_scope(url) as session:
        envmap = session.execute(
            sa.select(m.Envmap.blob).where(m.Envmap.status == STATUS_OK, m.Envmap.enabled, m.Envmap.blob.is_not(None))
            .order_by(m.Envmap.split, m.Envmap.name).limit(1)  # "train" sorts first
        ).scalar_one_or_none()
        materials = session.execute(sa.select(m.Material).where(m.Material.id.in_(ids), m.Material.status == STATUS_OK)
                                    ).scalars().all()
    if envmap is None:
        reason = "no envmap ingested (ingest envmaps first)"
        logger.info("material previews skipped: %s", reason)
        summary.skipped.append(("previews", reason))
        return summary
    try:
        renderer = renderer if renderer is not None else default_renderer(store)
    except Exception as exc:
        reason = f"renderer unavailable ({one_line(exc)})"
        logger.info("material previews skipped: %s", reason)
        summary.skipped.append(("previews", reason))
        return summary
    sphere = uv_sphere()
    camera = Camera(azimuth=0.0, elevation=0.35, distance=2.2, fov=30.0)
    env = EnvmapSpec(path=store.resolve(envmap))
    for material in materials:
        try:
            spec = MaterialSpec(
                name=material.name,
                substance=material.substance,
                maps={channel: store.resolve(ref) for channel, ref in (material.maps or {}).items()},
                params=dict(material.params or {}),
                scale=float(material.default_scale),
            )
            result = renderer.beauty(sphere, [spec], camera, env, size=size, spp=spp, background="white",
                                     record=False)  # one render per material: nothing to replay
            ref = store.put_image(result.srgb, "png")
        except Exception as exc:  # one material's failure must not stop the others
            logger.warning("material %s: preview failed: %s", material.name, one_line(exc))
            summary.warn(material.name, f"preview failed: {one_line(exc)}")
            continue
        with session_scope(url) as session:
            session.execute(sa.update(m.Material).where(m.Material.id == material.id).values(preview_blob=ref))
        summary.added.append(material.id)
    return summary
