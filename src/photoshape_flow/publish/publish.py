"""Stage: publish PhotoShapes (section 5.3): the renders and downloads of every candidate.

For each candidate and method (`publish.photoshapes`: what a candidate is, how one is loaded and
which envmap lights it) this stage:

1. renders the PhotoShape path traced under one studio envmap on a white background: the
   exemplar's view (the pair's coarse-alignment camera) plus a canonical turntable of `views`
   azimuths from the front (`views_of`, the same framing for every shape), recorded as Rendering rows
   ``kind="photoshape"``, ``key=f"{pair_id}/{method_key}/{view}"`` (views ``exemplar``,
   ``turntable-00`` ...), images ``srgb`` and ``alpha``;
2. renders the shape with its built-in materials at the exemplar's view (`publish.builtin_renders`),
   the baseline the gallery shows beside it;
3. exports the downloads (the chosen `export.formats`, the Mitsuba XML with the exemplar-view render's
   framed camera, film, spp and seed, so it renders that image again (`photoshapes.exemplar_render`), and
   `assignment.json`; see `export.bundle`) into ``<data_root>/exports/<method_key>/<pair_id>/``
   (`publish.downloads`). Exports live in a folder, not the blob store, because the multi-file
   formats (XML + PLY + EXR, OBJ + MTL + PNG) only work with their relative paths intact and users
   download them as they are. A manifest ``<data_root>/exports/<method_key>/<pair_id>.json``
   records params_hash, status and error.

Idempotent and resumable: a render is skipped when its row exists with status ok and the same
`params_hash` (mesh, materials and their maps, UV transforms, envmap, camera, size, spp, seed, code
version), an export when its manifest says ok with the same hash. A failing item is recorded
(``status="failed"`` row or manifest; a candidate whose inputs cannot be loaded, e.g. a missing map
blob, on its exemplar-view row) and the batch goes on; a re-run retries it.

The gallery built from these rows is `publish.gallery_site`; grades are `publish.grading`.
"""
from __future__ import annotations

import datetime as dt
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.export.bundle import export_photoshape
from photoshape_flow.export.formats import DEFAULT_FORMATS, parse_formats
from photoshape_flow.hashing import stable_hash
from photoshape_flow.pipeline.renderings import record_rendering
from photoshape_flow.profiles import DEFAULT_PUBLISH_METHOD, writing_stage
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.publish.builtin_renders import Lighting, render_builtin
from photoshape_flow.publish.downloads import export_dir, export_manifest
from photoshape_flow.publish.photoshapes import (
    UNREFINED_VIEW,
    PhotoShape,
    assignment_set_keys,
    candidate_method_keys,
    choose_envmap,
    exemplar_render,
    framed_views,
    load_photoshape,
    render_key,
    render_seed,
)
from photoshape_flow.publish.rendering import LazyRenderer, render_and_record
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK

log = logging.getLogger(__name__)

# part of every export's params_hash: bump it when the bundle's layout or a writer changes
# (v2: the Mitsuba XML carries the render's framed camera, seed and envmap; textures shared by content)
EXPORT_VERSION = 2

@dataclass
class PublishSummary:
    method: str
    candidates: int = 0
    without_assignments: int = 0  # asked-for pairs with no rank-1 rows of `method` yet (its stage has not run)
    rendered: int = 0
    skipped: int = 0
    failed: int = 0
    exported: int = 0
    export_skipped: int = 0
    export_failed: int = 0
    render_seconds: float = 0.0
    envmap: str | None = None
    errors: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def _existing(session: Session, kind: str, keys: Sequence[str]) -> dict[str, tuple[str, str]]:
    rows = session.execute(
        sa.select(m.Rendering.key, m.Rendering.params_hash, m.Rendering.status)
        .where(m.Rendering.kind == kind, m.Rendering.key.in_(list(keys)))
    ).all()
    return {key: (h, status) for key, h, status in rows}


def run_publish(
    pair_ids: Sequence[int] | None = None,
    method: str | None = None,
    settings: Settings | None = None,
    views: int = 8,
    size: int = 256,
    spp: int = 64,
    *,
    floor: bool = False,
    formats: Sequence[str] = DEFAULT_FORMATS,
    export: bool = True,
    renderer: RendererProtocol | None = None,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> PublishSummary:
    """Render and export every candidate of `method` (all pairs, or `pair_ids`); resumable, idempotent."""
    settings = settings or get_settings()
    formats = parse_formats(list(formats))
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    summary = PublishSummary(method=method or DEFAULT_PUBLISH_METHOD)
    lazy = LazyRenderer(store, renderer)
    with session_scope(url) as session:
        todo = candidate_method_keys(session, method, pair_ids)
        shown = assignment_set_keys(session, todo)
        envmap_row = choose_envmap(session)
        envmap_id = envmap_row.id if envmap_row is not None else None
        summary.envmap = envmap_row.name if envmap_row is not None else None
    summary.candidates = len(todo)
    if pair_ids is not None:
        summary.without_assignments = len(set(pair_ids) - {pair_id for pair_id, _ in todo})
    if summary.without_assignments:
        log.warning("publish: %d pair(s) have no rank-1 %s assignments yet; they publish once `photoshape run %s` "
                    "has written them", summary.without_assignments, summary.method,
                    writing_stage(summary.method))
    if envmap_row is None:
        log.warning("publish: no enabled envmap; rendering under a constant white sky")

    def fail(message: str) -> None:
        log.warning("publish: %s", message)
        summary.errors.append(message)

    for pair_id, method_key in counted(progress, "publish pairs", todo):
        try:
            with session_scope(url) as session:
                envmap = session.get(m.Envmap, envmap_id) if envmap_id is not None else None
                item = load_photoshape(session, store, pair_id, method_key, envmap)
        except Exception as exc:  # a broken candidate must not stop the batch
            summary.failed += 1
            message = f"pair {pair_id} ({method_key}): {type(exc).__name__}: {exc}"
            fail(message)
            with session_scope(url) as session:  # recorded on the exemplar view's row
                record_rendering(session, store, kind="photoshape", key=render_key(pair_id, method_key, "exemplar"),
                                 images={}, params={"method_key": method_key}, pair_id=pair_id,
                                 status=STATUS_FAILED, error=message[:2000])
            continue
        framed = framed_views(item.mesh, item.camera, views)
        jobs = [(render_key(pair_id, method_key, view), camera, item.materials) for view, camera in framed]
        if item.unrefined is not None:  # the gallery's before/after of the refinement (`fit.refine`)
            jobs.append((render_key(pair_id, method_key, UNREFINED_VIEW), framed[0][1], item.unrefined))
        with session_scope(url) as session:
            existing = _existing(session, "photoshape", [key for key, *_ in jobs])
        for key, camera, materials in jobs:
            seed = render_seed(settings.seed, "photoshape", key)
            params = {"camera": camera.to_dict(), "size": size, "spp": spp, "floor": floor, "seed": seed,
                      "method_key": method_key, "envmap": summary.envmap, "background": "white"}
            params_hash = stable_hash({**item.fingerprint, **params, "envmap_blob": item.fingerprint["envmap"]})
            if existing.get(key) == (params_hash, STATUS_OK):
                summary.skipped += 1
                continue
            # what the render shows, for the gallery and grades (not hashed: implied by the fingerprint)
            params = {**params, "assignment_set": shown.get((pair_id, method_key))}
            render_and_record(url, store, lazy, summary, fail, mesh=item.mesh, materials=materials, camera=camera,
                              envmap=item.envmap, jitters=item.uv_transforms, size=size, spp=spp, floor=floor,
                              seed=seed, row={"kind": "photoshape", "key": key, "params": params,
                                              "shape_id": item.shape_id, "pair_id": pair_id,
                                              "envmap_id": item.envmap_id, "params_hash": params_hash,
                                              "classifier_id": item.classifier_id})
        render_builtin(url, store, lazy, summary, fail, seed=settings.seed, pair_id=pair_id, shape_id=item.shape_id,
                       mesh=item.mesh, mesh_blob=item.fingerprint["mesh"], camera=item.camera, size=size, spp=spp,
                       floor=floor, lighting=Lighting(summary.envmap, item.fingerprint["envmap"], item.envmap_id,
                                                      item.envmap))
        if export:
            _export(item, formats, settings, store, size, spp, summary, fail, export_photoshape)
    log.info("publish %s: %d candidates, %d rendered, %d skipped, %d failed, %d exported (%d skipped, %d failed)",
             summary.method, summary.candidates, summary.rendered, summary.skipped, summary.failed,
             summary.exported, summary.export_skipped, summary.export_failed)
    summary.errors = summary.errors[:20]
    return summary


def _export(item: PhotoShape, formats: Sequence[str], settings: Settings, store: BlobStore, size: int, spp: int,
            summary: PublishSummary, fail: Any, export_photoshape: Any) -> None:
    out = export_dir(item.pair_id, item.method_key, settings)
    camera, seed = exemplar_render(item, settings.seed)  # the scene formats reproduce the exemplar-view render
    params_hash = stable_hash({**item.fingerprint, "document": item.document, "formats": list(formats),
                               "camera": camera.to_dict(), "size": size, "spp": spp, "seed": seed,
                               "export": EXPORT_VERSION})
    manifest = export_manifest(item.pair_id, item.method_key, settings)
    if manifest and manifest.get("status") == STATUS_OK and manifest.get("params_hash") == params_hash \
            and out.is_dir():
        summary.export_skipped += 1
        return
    record: dict[str, Any] = {"pair_id": item.pair_id, "method_key": item.method_key, "params_hash": params_hash,
                              "formats": list(formats), "updated_at": dt.datetime.now(dt.UTC).isoformat()}
    try:
        written = export_photoshape(out, item.mesh, item.materials, item.uv_transforms, item.document,
                                    formats=formats, envmap=item.envmap, camera=camera, seed=seed,
                                    resolve_ref=store.resolve, size=size, spp=spp)
        record.update(status=STATUS_OK, error=None,
                      files={k: v.relative_to(out).as_posix() for k, v in written.items()})
        summary.exported += 1
    except Exception as exc:
        message = f"export pair {item.pair_id} ({item.method_key}): {type(exc).__name__}: {exc}"
        record.update(status=STATUS_FAILED, error=message[:2000], files={})
        summary.export_failed += 1
        fail(message)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=2, sort_keys=True))
    tmp.replace(out.with_suffix(".json"))
