"""Stage: publish PhotoShapes (section 5.3): renders, downloads and the gallery's data.

A *candidate* is a non-excluded pair with rank-1 assignments for a method (the `photoshape_candidate`
view). For each candidate and method this stage:

1. renders the PhotoShape path traced under one studio envmap on a white background: the
   exemplar's view (the pair's coarse-alignment camera) plus a canonical turntable of `views`
   azimuths from the front (`views_of`, the same framing for every shape), recorded as Rendering rows
   ``kind="photoshape"``, ``key=f"{pair_id}/{method_key}/{view}"`` (views ``exemplar``,
   ``turntable-00`` ...), images ``srgb`` and ``alpha``;
2. renders the shape with its built-in materials at the exemplar's view (``kind="builtin"``,
   ``key=f"{pair_id}/exemplar"``), the baseline the gallery shows beside it;
3. exports the downloads (GLB, Mitsuba XML of the exemplar view, OBJ, `assignment.json`; see
   `export.bundle`) into ``<data_root>/exports/<method_key>/<pair_id>/``. Exports live in a folder,
   not the blob store, because the multi-file formats (XML + PLY + EXR, OBJ + MTL + PNG) only work
   with their relative paths intact and users download them as they are. A manifest
   ``<data_root>/exports/<method_key>/<pair_id>.json`` records params_hash, status and error.

The envmap is chosen deterministically: enabled and ok rows, preferring ``meta.studio`` true, then a
name containing "studio", then the lowest id; None (a constant white sky) when there is none.

Idempotent and resumable: a render is skipped when its row exists with status ok and the same
`params_hash` (mesh, materials and their maps, UV transforms, envmap, camera, size, spp, seed, code
version), an export when its manifest says ok with the same hash. A failing item is recorded
(``status="failed"`` row or manifest; a candidate whose inputs cannot be loaded, e.g. a missing map
blob, on its exemplar-view row) and the batch goes on; a re-run retries it.

Assignment UV transforms: ``Assignment.params["uv"] = {"scale", "rotation", "offset"}`` when the
inference stage recorded one, otherwise none (the texture-scale formula alone).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import zoom_to_fit
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.export.assignment import PartAssignment, Provenance, assignment_document
from photoshape_flow.export.formats import DEFAULT_FORMATS, parse_formats
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK

log = logging.getLogger(__name__)

CODE_VERSION = "publish-v1"
DEFAULT_METHOD = "classifier"
# elevation (rad), distance, horizontal fov (deg): the unit cube's bounding sphere (r = 0.87) fits the frame
TURNTABLE_CAMERA = (math.radians(20.0), 2.6, 40.0)


def _hash(payload: Any) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def item_seed(global_seed: int, kind: str, key: str) -> int:
    """A render seed derived from the global seed and the item's natural key."""
    return int.from_bytes(hashlib.sha256(f"{global_seed}/{kind}/{key}".encode()).digest()[:4], "little") >> 1


def safe_key(method_key: str) -> str:
    """A method key as a folder name (``classifier:3`` -> ``classifier-3``)."""
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in method_key)


def exports_root(settings: Settings | None = None) -> Path:
    return (settings or get_settings()).data_root / "exports"


def export_dir(pair_id: int, method_key: str, settings: Settings | None = None) -> Path:
    return exports_root(settings) / safe_key(method_key) / str(pair_id)


def export_manifest(pair_id: int, method_key: str, settings: Settings | None = None) -> dict[str, Any] | None:
    path = export_dir(pair_id, method_key, settings).with_suffix(".json")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


# -- what to publish ------------------------------------------------------------------------------
def candidate_method_keys(session: Session, method: str | None, pair_ids: Sequence[int] | None = None
                          ) -> list[tuple[int, str]]:
    """(pair_id, method_key) of every non-excluded candidate with rank-1 rows for `method`.

    `method` is a method name (``classifier`` takes each pair's newest classifier) or an exact
    method key (``classifier:3``, ``builtin``).
    """
    method = method or DEFAULT_METHOD
    query = (
        sa.select(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.method,
                  sa.func.max(m.Assignment.classifier_id))
        .join(m.Pair, m.Pair.id == m.Assignment.pair_id)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .where(m.Assignment.rank == 1, ~m.Pair.exclude, ~m.Shape.exclude, ~m.Exemplar.exclude)
        .group_by(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.method)
        .order_by(m.Assignment.pair_id)
    )
    if pair_ids is not None:
        query = query.where(m.Assignment.pair_id.in_(list(pair_ids)))
    best: dict[int, tuple[int, str]] = {}
    for pair_id, method_key, row_method, classifier_id in session.execute(query):
        if method_key == method:
            best[pair_id] = (1 << 62, method_key)  # an exact key always wins
        elif row_method == method and ":" not in method:
            rank = classifier_id or 0
            if pair_id not in best or best[pair_id][0] < rank:
                best[pair_id] = (rank, method_key)
    return [(pair_id, key) for pair_id, (_, key) in sorted(best.items())]


def choose_envmap(session: Session) -> m.Envmap | None:
    """The studio envmap every PhotoShape render uses (see the module docstring)."""
    rows = session.execute(
        sa.select(m.Envmap).where(m.Envmap.enabled, m.Envmap.status == STATUS_OK, m.Envmap.blob.is_not(None))
        .order_by(m.Envmap.id)
    ).scalars().all()
    if not rows:
        return None
    return min(rows, key=lambda e: (not (e.meta or {}).get("studio"), "studio" not in e.name.lower(), e.id))


def _provenance(role: str, row: Any) -> Provenance:
    return Provenance(role=role, id=row.id, name=getattr(row, "name", None) or getattr(row, "source_id", None),
                      source=getattr(row, "source", None), license=row.license, attribution=row.attribution,
                      source_url=row.source_url)


def _uv_transform(params: dict[str, Any] | None) -> Any:
    from photoshape_flow.render import UVTransform

    uv = (params or {}).get("uv")
    if not isinstance(uv, dict):
        return None
    offset = uv.get("offset", (0.0, 0.0))
    return UVTransform(float(uv.get("scale", 1.0)), float(uv.get("rotation", 0.0)),
                       (float(offset[0]), float(offset[1])))


@dataclass
class PhotoShape:
    """Everything needed to render and export one candidate with one method."""

    pair_id: int
    method_key: str
    shape_id: int
    exemplar_id: int
    classifier_id: int | None
    mesh: Any
    materials: list[Any]  # MaterialSpec | None (built-in) per part
    uv_transforms: list[Any]  # UVTransform | None per part
    camera: Any  # the exemplar's view
    document: dict[str, Any]  # assignment.json
    fingerprint: dict[str, Any]  # inputs that the renders depend on (for params_hash)
    envmap: Any = None  # EnvmapSpec
    envmap_id: int | None = None
    exemplar_blob: str | None = None
    material_rows: dict[int, Any] = field(default_factory=dict)


def load_photoshape(session: Session, store: BlobStore, pair_id: int, method_key: str,
                    envmap: m.Envmap | None = None) -> PhotoShape:
    """Read a candidate's rows and blobs into render/export inputs; a one-line error when incomplete."""
    from photoshape_flow.geometry.mesh import ShapeMesh
    from photoshape_flow.pipeline.training_renders import material_spec
    from photoshape_flow.render import Camera, EnvmapSpec

    pair = session.get(m.Pair, pair_id)
    if pair is None:
        raise ValueError(f"pair {pair_id}: no such pair")
    shape, exemplar = session.get(m.Shape, pair.shape_id), session.get(m.Exemplar, pair.exemplar_id)
    if shape is None or exemplar is None or not shape.mesh_blob:
        raise ValueError(f"pair {pair_id}: shape or exemplar missing, or the shape has no mesh")
    mesh = ShapeMesh.from_npz_bytes(store.read_bytes(shape.mesh_blob))
    parts = {p.index: p for p in session.execute(sa.select(m.Part).where(m.Part.shape_id == shape.id)).scalars()}
    rows = {
        a.part_id: a for a in session.execute(
            sa.select(m.Assignment).where(m.Assignment.pair_id == pair_id, m.Assignment.method_key == method_key,
                                          m.Assignment.rank == 1)
        ).scalars()
    }
    if not rows:
        raise ValueError(f"pair {pair_id}: no rank-1 assignments for {method_key}")
    material_ids = sorted({a.material_id for a in rows.values() if a.material_id is not None})
    material_rows = {r.id: r for r in session.execute(sa.select(m.Material).where(m.Material.id.in_(material_ids)))
                     .scalars()}
    specs: dict[int, Any] = {mid: material_spec(row, store) for mid, row in material_rows.items()}
    materials, jitters, assigned, fingerprint_parts = [], [], [], []
    classifier_id = None
    for part_mesh in mesh.parts:
        row_part = parts.get(part_mesh.index)
        a = rows.get(row_part.id) if row_part is not None else None
        spec = specs.get(a.material_id) if a is not None and a.material_id is not None else None
        jitter = _uv_transform(a.params) if a is not None and spec is not None else None
        materials.append(spec)
        jitters.append(jitter)
        classifier_id = classifier_id or (a.classifier_id if a is not None else None)
        mat = material_rows.get(a.material_id) if a is not None and a.material_id is not None else None
        assigned.append(PartAssignment(
            part_index=part_mesh.index, part_name=part_mesh.name,
            material_id=mat.id if mat else None, material_name=mat.name if mat else None,
            substance=(a.substance if a is not None else None) or (mat.substance if mat else None),
            score=a.score if a is not None else None, unobserved=bool(a.unobserved) if a is not None else False,
            uv_density=float(part_mesh.uv_density), material_scale=spec.scale if spec is not None else None,
            uv_transform=jitter.to_dict() if jitter is not None else None,
        ))
        fingerprint_parts.append({
            "part": part_mesh.index,
            "material": None if mat is None else [mat.id, mat.params_hash, mat.maps, mat.params, mat.default_scale],
            "builtin": part_mesh.builtin_material if spec is None else None,
            "uv": jitter.to_dict() if jitter is not None else None,
        })
    camera = Camera(float(pair.azimuth), float(pair.elevation), float(pair.camera_distance), float(pair.fov))
    envmap_spec = EnvmapSpec(path=store.resolve(envmap.blob)) if envmap is not None else None
    document = assignment_document(
        pair_id=pair_id, method_key=method_key,
        shape=_provenance("shape", shape), exemplar=_provenance("exemplar", exemplar), parts=assigned,
        materials=[_provenance("material", material_rows[mid]) for mid in material_ids],
        envmap=_provenance("envmap", envmap) if envmap is not None else None,
        camera=camera.to_dict(),
        extra={"hog_distance": pair.distance, "generator": CODE_VERSION},
    )
    fingerprint = {
        "code": CODE_VERSION, "mesh": shape.mesh_blob, "parts": fingerprint_parts,
        "envmap": None if envmap is None else envmap.blob,
    }
    return PhotoShape(
        pair_id=pair_id, method_key=method_key, shape_id=shape.id, exemplar_id=exemplar.id,
        classifier_id=classifier_id, mesh=mesh, materials=materials, uv_transforms=jitters, camera=camera,
        document=document, fingerprint=fingerprint, envmap=envmap_spec,
        envmap_id=envmap.id if envmap is not None else None, exemplar_blob=exemplar.image_blob,
        material_rows=material_rows,
    )


FRAME_MARGIN = 0.08  # fraction of the frame left around the shape in PhotoShape renders


def views_of(camera: Any, views: int) -> list[tuple[str, Any]]:
    """The exemplar's view, then a canonical turntable of `views` azimuths starting at the front (+z).

    The turntable is the same for every PhotoShape (elevation, distance and fov fixed by
    `TURNTABLE_CAMERA`), so the gallery compares shapes from identical angles and no turntable view
    repeats the exemplar's own.
    """
    elevation, distance, fov = TURNTABLE_CAMERA
    turntable = [
        (f"turntable-{i:02d}", camera.replace(azimuth=2.0 * math.pi * i / views, elevation=elevation,
                                              distance=distance, fov=fov))
        for i in range(max(0, views))
    ]
    return [("exemplar", camera), *turntable]


# -- the stage ------------------------------------------------------------------------------------
@dataclass
class PublishSummary:
    method: str
    candidates: int = 0
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
    renderer: Any = None,
) -> PublishSummary:
    """Render and export every candidate of `method` (all pairs, or `pair_ids`); resumable, idempotent."""
    from photoshape_flow.export.bundle import export_photoshape
    from photoshape_flow.pipeline.renderings import record_rendering

    settings = settings or get_settings()
    formats = parse_formats(list(formats))
    url = settings.resolved_database_url
    store = BlobStore(settings.blob_root)
    summary = PublishSummary(method=method or DEFAULT_METHOD)
    with session_scope(url) as session:
        todo = candidate_method_keys(session, method, pair_ids)
        envmap_row = choose_envmap(session)
        envmap_id = envmap_row.id if envmap_row is not None else None
        summary.envmap = envmap_row.name if envmap_row is not None else None
    summary.candidates = len(todo)
    if envmap_row is None:
        log.warning("publish: no enabled envmap; rendering under a constant white sky")

    def fail(message: str) -> None:
        log.warning("publish: %s", message)
        summary.errors.append(message)

    for pair_id, method_key in todo:
        try:
            with session_scope(url) as session:
                envmap = session.get(m.Envmap, envmap_id) if envmap_id is not None else None
                item = load_photoshape(session, store, pair_id, method_key, envmap)
        except Exception as exc:  # a broken candidate must not stop the batch
            summary.failed += 1
            message = f"pair {pair_id} ({method_key}): {type(exc).__name__}: {exc}"
            fail(message)
            with session_scope(url) as session:  # recorded on the exemplar view's row
                record_rendering(session, store, kind="photoshape", key=f"{pair_id}/{method_key}/exemplar",
                                 images={}, params={"method_key": method_key}, pair_id=pair_id,
                                 status=STATUS_FAILED, error=message[:2000])
            continue
        # Every view is framed like a product photo: the field of view narrowed until the shape fills it.
        framed = [(view, zoom_to_fit(item.mesh, camera, margin=FRAME_MARGIN)) for view, camera in
                  views_of(item.camera, views)]
        jobs = [("photoshape", f"{pair_id}/{method_key}/{view}", camera, item.materials, item.uv_transforms)
                for view, camera in framed]
        jobs.append(("builtin", f"{pair_id}/exemplar", framed[0][1], [None] * len(item.mesh.parts), None))
        with session_scope(url) as session:
            existing = {kind: _existing(session, kind, [k for kd, k, *_ in jobs if kd == kind])
                        for kind in ("photoshape", "builtin")}
        for kind, key, camera, materials, jitters in jobs:
            seed = item_seed(settings.seed, kind, key)
            fingerprint = dict(item.fingerprint)
            if kind == "builtin":
                fingerprint["parts"] = [{"part": p.index, "builtin": p.builtin_material} for p in item.mesh.parts]
            params = {"camera": camera.to_dict(), "size": size, "spp": spp, "floor": floor, "seed": seed,
                      "method_key": method_key, "envmap": summary.envmap, "background": "white"}
            params_hash = _hash({**fingerprint, **params})
            if existing[kind].get(key) == (params_hash, STATUS_OK):
                summary.skipped += 1
                continue
            if renderer is None:
                from photoshape_flow.render import Renderer

                renderer = Renderer(resolve=store.resolve)
            started = time.perf_counter()
            common = {"kind": kind, "key": key, "params": params, "shape_id": item.shape_id, "pair_id": pair_id,
                      "envmap_id": item.envmap_id, "params_hash": params_hash,
                      "classifier_id": item.classifier_id if kind == "photoshape" else None}
            try:
                result = renderer.beauty(item.mesh, materials, camera, item.envmap, size=size, spp=spp,
                                         uv_transforms=jitters, background="white", floor=floor, seed=seed)
            except Exception as exc:
                summary.failed += 1
                message = f"{kind} {key}: {type(exc).__name__}: {exc}"
                fail(message)
                with session_scope(url) as session:
                    record_rendering(session, store, images={}, status=STATUS_FAILED, error=message[:2000],
                                     **common)
                continue
            seconds = time.perf_counter() - started
            summary.render_seconds += seconds
            alpha = (result.alpha.clip(0.0, 1.0) * 255.0 + 0.5).astype("uint8")
            with session_scope(url) as session:
                record_rendering(session, store, images={"srgb": result.srgb, "alpha": alpha}, seconds=seconds,
                                 saturated_fraction=result.saturated_fraction, **common)
            summary.rendered += 1
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
    params_hash = _hash({**item.fingerprint, "document": item.document, "formats": list(formats),
                         "camera": item.camera.to_dict(), "size": size, "spp": spp})
    manifest = export_manifest(item.pair_id, item.method_key, settings)
    if manifest and manifest.get("status") == STATUS_OK and manifest.get("params_hash") == params_hash \
            and out.is_dir():
        summary.export_skipped += 1
        return
    record: dict[str, Any] = {"pair_id": item.pair_id, "method_key": item.method_key, "params_hash": params_hash,
                              "formats": list(formats), "updated_at": dt.datetime.now(dt.UTC).isoformat()}
    try:
        written = export_photoshape(out, item.mesh, item.materials, item.uv_transforms, item.document,
                                    formats=formats, envmap=item.envmap, camera=item.camera,
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


# -- exports on demand (`photoshape export`) ------------------------------------------------------
def export_candidates(
    out_dir: str | Path,
    pair_ids: Sequence[int] | None = None,
    method: str | None = None,
    formats: Sequence[str] = DEFAULT_FORMATS,
    settings: Settings | None = None,
    *,
    size: int = 512,
    spp: int = 128,
) -> list[dict[str, Any]]:
    """Write each candidate's downloads into ``out_dir/<pair_id>-<method_key>/``; one result per item.

    Each result: ``{"pair_id", "method_key", "status", "error", "files": {format: path}}``; a failing
    candidate is reported and the others go on.
    """
    from photoshape_flow.export.bundle import export_photoshape

    settings = settings or get_settings()
    formats = parse_formats(list(formats))
    store = BlobStore(settings.blob_root)
    url = settings.resolved_database_url
    with session_scope(url) as session:
        todo = candidate_method_keys(session, method, pair_ids)
        envmap = choose_envmap(session)
        envmap_id = envmap.id if envmap is not None else None
    missing = sorted(set(pair_ids or ()) - {p for p, _ in todo})
    results: list[dict[str, Any]] = [
        {"pair_id": p, "method_key": None, "status": STATUS_FAILED, "error": f"pair {p}: not a candidate for "
         f"{method or DEFAULT_METHOD} (no rank-1 assignments, or excluded)", "files": {}} for p in missing
    ]
    for pair_id, method_key in todo:
        result: dict[str, Any] = {"pair_id": pair_id, "method_key": method_key, "files": {}}
        try:
            with session_scope(url) as session:
                env = session.get(m.Envmap, envmap_id) if envmap_id is not None else None
                item = load_photoshape(session, store, pair_id, method_key, env)
            target = Path(out_dir) / f"{pair_id}-{safe_key(method_key)}"
            written = export_photoshape(target, item.mesh, item.materials, item.uv_transforms, item.document,
                                        formats=formats, envmap=item.envmap, camera=item.camera,
                                        resolve_ref=store.resolve, size=size, spp=spp)
            result.update(status=STATUS_OK, error=None, files={k: str(v) for k, v in written.items()})
        except Exception as exc:
            result.update(status=STATUS_FAILED, error=f"pair {pair_id} ({method_key}): {type(exc).__name__}: {exc}")
            log.warning("export: %s", result["error"])
        results.append(result)
    return sorted(results, key=lambda r: r["pair_id"])


# -- curation -------------------------------------------------------------------------------------
def record_grade(session: Session, pair_id: int, label: str, note: str | None = None, grader: str = "user") -> int:
    """Upsert the grader's verdict on a PhotoShape; returns the Grade row id.

    Raises ValueError (one line) for an unknown label or pair.
    """
    from photoshape_flow.db.upsert import upsert
    from photoshape_flow.vocab import GRADES

    if label not in GRADES:
        raise ValueError(f"unknown grade {label!r}; valid grades: {', '.join(GRADES)}")
    if session.get(m.Pair, pair_id) is None:
        raise ValueError(f"pair {pair_id}: no such pair")
    row = {"pair_id": pair_id, "label": label, "note": note, "grader": grader or "user"}
    return upsert(session, m.Grade, row, key=["pair_id", "grader"])[0]


# -- gallery data ---------------------------------------------------------------------------------
def gallery_data(session: Session, store: BlobStore, method: str | None = None,
                 settings: Settings | None = None) -> tuple[list[Any], list[Any]]:
    """`GalleryEntry` per candidate of `method` and `GalleryMaterial` per material they use."""
    from photoshape_flow.export.gallery import GalleryEntry, GalleryMaterial, GalleryPart

    settings = settings or get_settings()

    def blob_path(ref: str | None) -> Path | None:
        if not ref:
            return None
        path = store.path(ref)
        return path if path.is_file() else None

    entries: list[GalleryEntry] = []
    used: set[int] = set()
    for pair_id, method_key in candidate_method_keys(session, method):
        pair = session.get(m.Pair, pair_id)
        shape, exemplar = session.get(m.Shape, pair.shape_id), session.get(m.Exemplar, pair.exemplar_id)
        rows = session.execute(
            sa.select(m.Part, m.Assignment, m.Material)
            .join(m.Assignment, sa.and_(m.Assignment.part_id == m.Part.id, m.Assignment.pair_id == pair_id,
                                        m.Assignment.method_key == method_key, m.Assignment.rank == 1), isouter=True)
            .join(m.Material, m.Material.id == m.Assignment.material_id, isouter=True)
            .where(m.Part.shape_id == shape.id).order_by(m.Part.index)
        ).all()
        parts = [
            GalleryPart(index=part.index, name=part.name, material_id=mat.id if mat else None,
                        material_name=mat.name if mat else None,
                        substance=(a.substance if a else None) or (mat.substance if mat else None),
                        score=a.score if a else None, unobserved=bool(a.unobserved) if a else False)
            for part, a, mat in rows
        ]
        used.update(p.material_id for p in parts if p.material_id is not None)
        renders = session.execute(
            sa.select(m.Rendering.key, m.Rendering.blobs).where(
                m.Rendering.kind == "photoshape", m.Rendering.key.like(f"{pair_id}/{method_key}/%"),
                m.Rendering.status == STATUS_OK)
        ).all()
        views = sorted(((key.rsplit("/", 1)[-1], blob_path((blobs or {}).get("srgb"))) for key, blobs in renders),
                       key=lambda v: (v[0] != "exemplar", v[0]))
        builtin = session.execute(
            sa.select(m.Rendering.blobs).where(m.Rendering.kind == "builtin", m.Rendering.key == f"{pair_id}/exemplar",
                                              m.Rendering.status == STATUS_OK)
        ).scalar_one_or_none()
        iou = session.execute(
            sa.select(m.Alignment.iou_crf).where(m.Alignment.pair_id == pair_id, m.Alignment.method == "flow-crf")
        ).scalar_one_or_none()
        grade = session.execute(
            sa.select(m.Grade).where(m.Grade.pair_id == pair_id).order_by(m.Grade.updated_at.desc(), m.Grade.id.desc())
        ).scalars().first()
        manifest = export_manifest(pair_id, method_key, settings) or {}
        folder = export_dir(pair_id, method_key, settings)
        downloads = {fmt: folder / rel for fmt, rel in (manifest.get("files") or {}).items()
                     if manifest.get("status") == STATUS_OK and (folder / rel).exists()}
        material_rows = [mat for _, _, mat in rows if mat is not None]
        licences = [_provenance("shape", shape), _provenance("exemplar", exemplar),
                    *{mat.id: _provenance("material", mat) for mat in material_rows}.values()]
        entries.append(GalleryEntry(
            pair_id=pair_id, method_key=method_key, shape_name=shape.name or shape.source_id,
            exemplar_name=exemplar.name or exemplar.source_id, parts=parts,
            exemplar_image=blob_path(exemplar.image_blob),
            builtin_image=blob_path((builtin or {}).get("srgb")),
            renders=[(view, path) for view, path in views if path is not None],
            hog_distance=pair.distance, alignment_iou=iou,
            grade=grade.label if grade else None, grade_note=grade.note if grade else None,
            grader=grade.grader if grade else None, downloads=downloads,
            licenses=[{k: getattr(p, k) for k in ("role", "name", "license", "attribution", "source_url")}
                      for p in licences],
        ))
    materials = [
        GalleryMaterial(id=row.id, name=row.name, substance=row.substance, preview=blob_path(row.preview_blob),
                        license=row.license, attribution=row.attribution, source_url=row.source_url)
        for row in session.execute(sa.select(m.Material).where(m.Material.id.in_(sorted(used)))).scalars()
    ]
    return entries, materials


def write_gallery_site(out_dir: str | Path, method: str | None = None, settings: Settings | None = None) -> Path:
    """Gather the candidates from the database and write the static gallery; returns index.html."""
    from photoshape_flow.export.gallery import write_gallery

    settings = settings or get_settings()
    store = BlobStore(settings.blob_root)
    with session_scope(settings.resolved_database_url) as session:
        entries, materials = gallery_data(session, store, method, settings)
    return write_gallery(out_dir, entries, materials)


def write_contact_sheet(out: str | Path, method: str | None = None, settings: Settings | None = None,
                        **kwargs: Any) -> Path:
    """The best candidates of `method` as one PNG (`export.contact_sheet`); returns its path."""
    from photoshape_flow.export.contact_sheet import contact_sheet

    settings = settings or get_settings()
    store = BlobStore(settings.blob_root)
    with session_scope(settings.resolved_database_url) as session:
        entries, _ = gallery_data(session, store, method, settings)
    return contact_sheet(entries, out, **kwargs)
