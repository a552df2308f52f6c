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


def _pair(session, shape_id: int, exemplar_id: int, rank: int):  # type: ignore[no-untyped-def]
    pair = m.Pair(shape_id=shape_id, exemplar_id=exemplar_id, rank=rank, distance=1.0, azimuth=0.0, elevation=0.0,
                  fov=30.0, camera_distance=2.0)
    session.add(pair)
    session.flush()
    return pair


def test_rejected_is_counted_apart_from_failed(db_url: str) -> None:
    from photoshape_flow.pipeline.progress import ingest_progress, rendering_progress, training_renders_progress

    with session_scope(db_url) as session:
        session.add_all([
            m.Shape(source="test", source_id="good"),
            m.Shape(source="test", source_id="malformed", status="rejected", error="no faces"),
            m.Shape(source="test", source_id="crashed", status="failed", error="importer killed"),
            m.Envmap(name="sky", status="rejected", error="not equirectangular"),
            m.Rendering(kind="training", key="a"),
            m.Rendering(kind="training", key="b", status="rejected", error="part not visible"),
            m.Rendering(kind="bootstrap", key="c", status="rejected"),
            m.Rendering(kind="bootstrap", key="e", status="rejected", error="saturated fraction 0.250 > 0.05"),
            m.Rendering(kind="bootstrap", key="f", status="rejected", error="saturated fraction 0.688 > 0.05"),
            m.Rendering(kind="training", key="d", status="failed", error="renderer crashed"),
            m.Rendering(kind="photoshape", key="1/fit:1/exemplar"),
        ])
    with session_scope(db_url) as session:
        ingest, renders = ingest_progress(session), training_renders_progress(session)
        kinds = rendering_progress(session)
    assert (ingest.done, ingest.pending, ingest.failed, ingest.rejected) == (1, 0, 1, 2)
    # the training round's renders only: the bootstrap round's belong to the substances stage
    assert (renders.done, renders.pending, renders.failed, renders.rejected) == (1, 0, 1, 1)
    assert [(k.kind, k.stage, k.ok, k.failed, k.rejected) for k in kinds] == [
        ("bootstrap", "substances", 0, 0, 3), ("training", "training-renders", 1, 1, 1),
        ("photoshape", "publish", 1, 0, 0)]
    # reasons summarised without their numbers, most frequent first, each with one full message
    assert kinds[0].reasons_text() == ("2 saturated fraction (e.g. saturated fraction 0.250 > 0.05); "
                                       "1 no reason recorded")
    assert kinds[1].reasons_text() == "1 part not visible"


def test_publish_pending_counts_pairs_up_to_the_last_runs_max_rank(db_url: str) -> None:
    from photoshape_flow.pipeline.progress import assumed_profile, publish_progress
    from photoshape_flow.profiles import resolve_profile

    with session_scope(db_url) as session:
        shape = m.Shape(source="test", source_id="chair")
        session.add(shape)
        session.flush()
        part = m.Part(shape_id=shape.id, index=1, name="seat")
        exemplars = [m.Exemplar(source="test", source_id=f"photo{i}") for i in range(3)]
        session.add_all([part, *exemplars])
        session.flush()
        pairs = [_pair(session, shape.id, e.id, rank) for rank, e in enumerate(exemplars, start=1)]
        session.add_all([m.Assignment(pair_id=p.id, part_id=part.id, method="classifier", method_key="classifier:1")
                         for p in pairs])
        session.add(m.Rendering(kind="photoshape", key="pair-1", pair_id=pairs[0].id))
        session.add(m.Rendering(kind="photoshape", key="pair-2", pair_id=pairs[1].id, status="failed"))

    def counts() -> tuple[int, int, int]:
        with session_scope(db_url) as session:
            p = publish_progress(session)
            return p.done, p.pending, p.failed

    # no run recorded: the default profile (max_rank 12); the third pair is waiting, the failed one is failed
    with session_scope(db_url) as session:
        assert assumed_profile(session).run_id is None
    assert counts() == (1, 1, 1)
    with session_scope(db_url) as session:  # the tiny profile publishes each shape's rank-1 pair only
        record = resolve_profile("tiny").record()
        session.add(m.PipelineRun(origin="cli", profile_name="tiny", profile=record["profile"], status="ok"))
    assert counts() == (1, 0, 1)
    with session_scope(db_url) as session:  # the newest run decides, overrides included
        record = resolve_profile("tiny", ["publish.max_rank=3"]).record()
        session.add(m.PipelineRun(origin="cli", profile_name="tiny", overrides=record["overrides"],
                                  profile=record["profile"], status="ok"))
    assert counts() == (1, 1, 1)
    with session_scope(db_url) as session:
        described = assumed_profile(session).describe()
    assert described == "profile tiny --set publish.max_rank=3 (last run #2; publish: pairs up to rank 3)"
