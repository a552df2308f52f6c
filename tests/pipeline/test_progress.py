"""Stage progress counts only the rows each stage itself writes."""

from __future__ import annotations

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.progress import coarse_alignment_progress


def coarse(url: str) -> tuple[int, int, int]:
    with session_scope(url) as session:
        p = coarse_alignment_progress(session)
        return p.done, p.pending, p.failed


def test_coarse_alignment_ignores_ingest_dedupe_features(db_url: str) -> None:
    with session_scope(db_url) as session:
        shape = m.Shape(source="test", source_id="chair")
        photo = m.Exemplar(source="test", source_id="photo")
        other = m.Exemplar(source="test", source_id="other")
        vset = m.ViewpointSet(name="v", num_views=1, cameras=[[0.0, 0.0, 2.0, 50.0]])
        session.add_all([shape, photo, other, vset])
        session.flush()
        ids = shape.id, photo.id, other.id, vset.id
        # what ingest writes for every exemplar: not coarse-alignment work
        session.add_all([m.ExemplarFeature(exemplar_id=e, descriptor="dedupe-hog", dims=441) for e in ids[1:3]])
    assert coarse(db_url) == (0, 3, 0)
    with session_scope(db_url) as session:
        session.add(m.ViewFeature(shape_id=ids[0], viewpoint_set_id=ids[3], descriptor="hog-insensitive9"))
        session.add(m.ExemplarFeature(exemplar_id=ids[1], descriptor="hog-insensitive9", dims=1352))
        session.add(m.ExemplarFeature(exemplar_id=ids[2], descriptor="hog-insensitive9", status="failed"))
    assert coarse(db_url) == (2, 0, 1)
