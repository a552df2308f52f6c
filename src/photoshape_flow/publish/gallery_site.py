"""The gallery's data from the database, and the gallery site and contact sheet written from it.

`export.gallery` and `export.contact_sheet` are pure functions of `GalleryEntry` values; this
module gathers those values: each candidate's parts and assignments, its renders, alignment IoU,
grade, downloads (from the export manifests) and licences.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.export.contact_sheet import contact_sheet
from photoshape_flow.export.gallery import GalleryEntry, GalleryMaterial, GalleryPart, write_gallery
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.publish.downloads import export_dir, export_manifest
from photoshape_flow.publish.grading import current_grades
from photoshape_flow.publish.photoshapes import UNREFINED_VIEW, candidate_method_keys, provenance
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_OK


def gallery_data(session: Session, store: BlobStore, method: str | None = None,
                 settings: Settings | None = None, progress: Progress | None = None) -> tuple[list[Any], list[Any]]:
    """`GalleryEntry` per candidate of `method` and `GalleryMaterial` per material they use."""
    settings = settings or get_settings()

    def blob_path(ref: str | None) -> Path | None:
        if not ref:
            return None
        return store.resolve(ref) if store.exists(ref) else None

    entries: list[GalleryEntry] = []
    used: set[int] = set()
    candidates = candidate_method_keys(session, method)
    grades = current_grades(session, candidates)  # grades of what each PhotoShape shows now
    for pair_id, method_key in counted(progress, "gallery candidates", candidates):
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
                        score=a.score if a else None, unobserved=bool(a.unobserved) if a else False,
                        posterior=a.posterior if a else None, refinement=a.refinement if a else None)
            for part, a, mat in rows
        ]
        used.update(p.material_id for p in parts if p.material_id is not None)
        renders = session.execute(
            sa.select(m.Rendering.key, m.Rendering.blobs, m.Rendering.params).where(
                m.Rendering.kind == "photoshape", m.Rendering.key.like(f"{pair_id}/{method_key}/%"),
                m.Rendering.status == STATUS_OK)
        ).all()
        shown = {(params or {}).get("assignment_set") for key, _, params in renders if key.endswith("/exemplar")}
        views = sorted(((key.rsplit("/", 1)[-1], blob_path((blobs or {}).get("srgb"))) for key, blobs, _ in renders),
                       key=lambda v: (v[0] != "exemplar", v[0]))
        unrefined = dict(views).get(UNREFINED_VIEW)  # before refinement: shown beside the exemplar view
        views = [(view, path) for view, path in views if view != UNREFINED_VIEW]
        builtin = session.execute(
            sa.select(m.Rendering.blobs).where(m.Rendering.kind == "builtin", m.Rendering.key == f"{pair_id}/exemplar",
                                              m.Rendering.status == STATUS_OK)
        ).scalar_one_or_none()
        iou = session.execute(
            sa.select(m.Alignment.iou_crf).where(m.Alignment.pair_id == pair_id, m.Alignment.method == "flow-crf")
        ).scalar_one_or_none()
        grade = grades.get((pair_id, method_key))
        manifest = export_manifest(pair_id, method_key, settings) or {}
        folder = export_dir(pair_id, method_key, settings)
        downloads = {fmt: folder / rel for fmt, rel in (manifest.get("files") or {}).items()
                     if manifest.get("status") == STATUS_OK and (folder / rel).exists()}
        material_rows = [mat for _, _, mat in rows if mat is not None]
        licences = [provenance("shape", shape), provenance("exemplar", exemplar),
                    *{mat.id: provenance("material", mat) for mat in material_rows}.values()]
        entries.append(GalleryEntry(
            pair_id=pair_id, method_key=method_key, shape_name=shape.name or shape.source_id,
            exemplar_name=exemplar.name or exemplar.source_id, parts=parts,
            exemplar_image=blob_path(exemplar.image_blob),
            builtin_image=blob_path((builtin or {}).get("srgb")), unrefined_image=unrefined,
            renders=[(view, path) for view, path in views if path is not None],
            hog_distance=pair.distance, alignment_iou=iou,
            grade=grade.label if grade else None, grade_note=grade.note if grade else None,
            grader=grade.grader if grade else None, downloads=downloads,
            assignment_set=next(iter(shown - {None}), None),
            licenses=[{k: getattr(p, k) for k in ("role", "name", "license", "attribution", "source_url")}
                      for p in licences],
        ))
    materials = [
        GalleryMaterial(id=row.id, name=row.name, substance=row.substance, preview=blob_path(row.preview_blob),
                        license=row.license, attribution=row.attribution, source_url=row.source_url)
        for row in session.execute(sa.select(m.Material).where(m.Material.id.in_(sorted(used)))).scalars()
    ]
    return entries, materials


class GallerySite(NamedTuple):
    """A written gallery: its index.html and how many candidates are published (listed there) or not."""

    index: Path
    published: int
    waiting: int


def write_gallery_site(out_dir: str | Path, method: str | None = None, settings: Settings | None = None,
                       progress: Progress | None = None, store: BlobStore | None = None) -> GallerySite:
    """Gather the candidates from the database and write the static gallery."""
    settings = settings or get_settings()
    store = store if store is not None else default_store(settings)
    with session_scope(settings.resolved_database_url) as session:
        entries, materials = gallery_data(session, store, method, settings, progress)
    index = write_gallery(out_dir, entries, materials)
    published = sum(entry.published for entry in entries)
    return GallerySite(index, published, len(entries) - published)


def write_contact_sheet(out: str | Path, method: str | None = None, settings: Settings | None = None,
                        **kwargs: Any) -> Path:
    """The best candidates of `method` as one PNG (`export.contact_sheet`); returns its path."""
    settings = settings or get_settings()
    store = default_store(settings)
    with session_scope(settings.resolved_database_url) as session:
        entries, _ = gallery_data(session, store, method, settings)
    return contact_sheet(entries, out, **kwargs)
