"""Coarse alignment stage: viewpoint sets, idempotent and incremental runs, failures, evaluation.

A painter's-algorithm numpy rasteriser stands in for Mitsuba, so these tests need no renderer.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import sqlalchemy as sa

from photoshape_flow.align.descriptors import HogParams
from photoshape_flow.align.index import ArrayDatabase
from photoshape_flow.align.retrieval import search
from photoshape_flow.align.viewpoints import ViewpointParams, viewpoints
from photoshape_flow.alignment.coarse.pairs import DROPPED_REASON
from photoshape_flow.alignment.coarse.reverse_index import match_scope
from photoshape_flow.alignment.coarse.viewpoint_sets import ensure_viewpoint_set
from photoshape_flow.alignment.coarse_alignment import (
    CoarseConfig,
    evaluate_coarse_alignment,
    load_reverse_index,
    run_coarse_alignment,
)
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

VP = ViewpointParams(num_rings=3, equator_azimuths=12)
CONFIG = CoarseConfig(
    viewpoint_set="test-small", viewpoint_params=VP, hog=HogParams(render_size=96, channels="all31"),
    exemplar_topk=2, shape_topn=2,
)


class NumpyRenderer:
    """Flat-shaded painter's-algorithm rasteriser with the `Renderer.sweep` / `part_ids` interface."""

    def _draw(self, shape, camera, size: int):  # type: ignore[no-untyped-def]
        import cv2

        faces = []
        for part in shape.parts:
            pts, depth = camera.project(part.vertices, size)
            tri = part.vertices[part.faces].astype(np.float64)
            normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            view = camera.position - tri.mean(1)
            view /= np.linalg.norm(view, axis=1, keepdims=True)
            shade = 0.2 + 0.6 * np.abs((normal * view).sum(1))
            for f, d, s in zip(part.faces, depth[part.faces].mean(1), shade, strict=True):
                faces.append((float(d), pts[f], part.index, float(s)))
        ids = np.zeros((size, size), np.uint16)
        grey = np.ones((size, size), np.float32)
        for _, poly, index, s in sorted(faces, key=lambda t: -t[0]):
            p = np.round(poly * 16).astype(np.int32)
            cv2.fillConvexPoly(ids, p, int(index), lineType=cv2.LINE_8, shift=4)
            cv2.fillConvexPoly(grey, p, s, lineType=cv2.LINE_8, shift=4)
        return ids, grey

    def sweep(self, shape, cameras, size: int = 100, shaded: bool = True):  # type: ignore[no-untyped-def]
        drawn = [self._draw(shape, c, size) for c in cameras]
        return SimpleNamespace(part_ids=np.stack([d[0] for d in drawn]), shaded=np.stack([d[1] for d in drawn]))

    def part_ids(self, shape, camera, size: int = 256):  # type: ignore[no-untyped-def]
        return self._draw(shape, camera, size)[0]


def chair(back: float, arm: bool, leg: float):  # type: ignore[no-untyped-def]
    parts = [
        box_part(1, (0, 0, 0), (0.3, 0.04, 0.3), "seat"),
        box_part(2, (0, back / 2, -0.27), (0.3, back / 2, 0.03), "back"),
        box_part(3, (0.2, -leg / 2, 0.2), (0.03, leg / 2, 0.03), "leg"),
        box_part(4, (-0.2, -leg / 2, -0.2), (0.03, leg / 2, 0.03), "leg2"),
    ]
    if arm:
        parts.append(box_part(5, (0.28, 0.12, 0.0), (0.02, 0.1, 0.25), "arm"))
    return normalise_to_unit_cube(parts)


SHAPES = {"s0": chair(0.5, True, 0.4), "s1": chair(0.25, False, 0.45), "s2": chair(0.7, False, 0.2)}


def add_shape(url: str, store, source_id: str, mesh) -> int:  # type: ignore[no-untyped-def]
    blob = store.put_bytes(mesh.to_npz_bytes() if mesh is not None else b"not a mesh", "npz")
    with session_scope(url) as session:
        row = m.Shape(source="test", source_id=source_id, mesh_blob=blob, category="chair")
        session.add(row)
        session.flush()
        return row.id


def add_exemplar(url: str, store, source_id: str, mesh, view: int) -> int:  # type: ignore[no-untyped-def]
    cam = viewpoints(VP)[view]
    cam = cam.replace(azimuth=cam.azimuth + math.radians(2.0))  # a little off the grid
    ids, grey = NumpyRenderer()._draw(mesh, cam, 160)
    rgb = np.repeat((grey * 255).round().astype(np.uint8)[..., None], 3, axis=2)
    with session_scope(url) as session:
        row = m.Exemplar(
            source="test", source_id=source_id, category="chair", image_blob=store.put_image(rgb),
            mask_blob=store.put_image(((ids > 0) * 255).astype(np.uint8)), size=160,
        )
        session.add(row)
        session.flush()
        return row.id


def counts(url: str) -> dict[str, int]:
    with session_scope(url) as session:
        return {
            t.__tablename__: session.execute(sa.select(sa.func.count()).select_from(t)).scalar_one()
            for t in (m.ViewpointSet, m.ViewFeature, m.ExemplarFeature, m.ExemplarMatch, m.Pair)
        }


def reference_lists(url: str, store, config: CoarseConfig) -> dict[int, list[int]]:  # type: ignore[no-untyped-def]
    """From-scratch exact search over every ok feature, for comparing with the incremental index."""
    with session_scope(url) as session:
        vf = session.execute(
            sa.select(m.ViewFeature.shape_id, m.ViewFeature.feature_blob)
            .join(m.Shape, m.Shape.id == m.ViewFeature.shape_id)
            .where(m.ViewFeature.status == "ok", ~m.Shape.exclude)
            .order_by(m.ViewFeature.shape_id)
        ).all()
        ef = session.execute(
            sa.select(m.ExemplarFeature.exemplar_id, m.ExemplarFeature.feature_blob)
            .where(m.ExemplarFeature.descriptor == config.hog.name)
            .order_by(m.ExemplarFeature.exemplar_id)
        ).all()
    db = np.stack([store.load_array(b) for _, b in vf])
    q = np.stack([store.load_array(b).astype(np.float32) for _, b in ef])
    found = search(q, ArrayDatabase(db), config.exemplar_topk)
    sids = [s for s, _ in vf]
    return {e: [sids[i] for i in found.shapes[j] if i >= 0] for j, (e, _) in enumerate(ef)}


def test_distance_cutoff_defaults_to_the_channel_sets_calibration() -> None:
    assert CoarseConfig().distance_cutoff == 43.0  # insensitive9
    assert CoarseConfig(max_distance=5.0).distance_cutoff == 5.0
    assert CoarseConfig(max_distance=math.inf).distance_cutoff is None


def test_ensure_viewpoint_set_is_named_versioned_and_immutable(db_url: str) -> None:
    with session_scope(db_url) as session:
        paper = ensure_viewpoint_set(session)
        assert paper.num_views == 456 and len(paper.cameras) == 456
        assert ensure_viewpoint_set(session).id == paper.id
        small = ensure_viewpoint_set(session, "test-small", 1, VP)
        assert small.id != paper.id and small.num_views == len(viewpoints(VP))
        with pytest.raises(ValueError, match="use a new version"):
            ensure_viewpoint_set(session, "test-small", 1, ViewpointParams(num_rings=2))
        other = ensure_viewpoint_set(session, "test-small", 2, ViewpointParams(num_rings=2))
        assert other.id not in (paper.id, small.id)
        with pytest.raises(ValueError, match="unknown viewpoint set"):
            ensure_viewpoint_set(session, "nope")


@pytest.fixture(params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def stage_db(request: pytest.FixtureRequest, settings_env, monkeypatch: pytest.MonkeyPatch):  # type: ignore[no-untyped-def]
    """The stage's database, migrated: the test data root's SQLite file, or a fresh PostgreSQL one."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db.session import get_engine

    if request.param == "postgresql":
        monkeypatch.setenv("PHOTOSHAPE_DATABASE_URL", request.getfixturevalue("pg_url"))
        get_settings.cache_clear()
        get_engine.cache_clear()
    url = get_settings().resolved_database_url
    migrate.upgrade(url)
    yield url
    get_engine(url).dispose()


def test_pipeline_is_idempotent_incremental_and_exact(stage_db: str, store) -> None:  # type: ignore[no-untyped-def]
    db_url = stage_db
    renderer = NumpyRenderer()
    sid = {k: add_shape(db_url, store, k, mesh) for k, mesh in SHAPES.items()}
    broken = add_shape(db_url, store, "broken", None)
    e0 = add_exemplar(db_url, store, "e0", SHAPES["s0"], view=4)
    e1 = add_exemplar(db_url, store, "e1", SHAPES["s1"], view=20)

    first = run_coarse_alignment(config=CONFIG, renderer=renderer)
    assert first["view_features"]["computed"] == 3 and first["view_features"]["failed"] == 1
    assert first["exemplar_features"]["computed"] == 2
    assert first["pairs"]["full"] == 2 and first["pairs"]["pairs_written"] > 0
    with session_scope(db_url) as session:
        failed = session.execute(sa.select(m.ViewFeature).where(m.ViewFeature.shape_id == broken)).scalar_one()
        assert failed.status == "failed" and failed.error and "\n" not in failed.error
        index = load_reverse_index(session, CONFIG)
        assert index[e0][0, :2].tolist() == [sid["s0"], 4] and index[e1][0, :2].tolist() == [sid["s1"], 20]
        pair = session.execute(
            sa.select(m.Pair).where(m.Pair.shape_id == sid["s0"], m.Pair.exemplar_id == e0)
        ).scalar_one()
        assert pair.rank == 1 and pair.exemplar_rank == 1 and pair.view_index == 4
        assert pair.azimuth == pytest.approx(viewpoints(VP)[4].azimuth) and pair.fov == 50.0
        assert pair.descriptor == "hog-all31" and pair.params_hash
        vf = session.execute(sa.select(m.ViewFeature).where(m.ViewFeature.shape_id == sid["s0"])).scalar_one()
        shard = store.load_array(vf.feature_blob)
        assert shard.dtype == np.float16 and shard.shape == (len(viewpoints(VP)), 13 * 13 * 31)
        # the reverse index is plain rows: rank 1 of e0 is s0 at view 4, k rows per exemplar
        best = session.execute(
            sa.select(m.ExemplarMatch).where(m.ExemplarMatch.exemplar_id == e0, m.ExemplarMatch.rank == 1)
        ).scalar_one()
        assert (best.shape_id, best.view_index, best.descriptor) == (sid["s0"], 4, "hog-all31")
        assert best.scope == match_scope(CONFIG) == "" and best.searched_at is not None and best.params_hash
    before = counts(db_url)
    assert before["view_feature"] == 4 and before["exemplar_feature"] == 2  # one descriptor per exemplar
    assert before["exemplar_match"] == 2 * CONFIG.exemplar_topk

    again = run_coarse_alignment(config=CONFIG, renderer=renderer)
    assert counts(db_url) == before
    assert again["view_features"]["computed"] == 0 and again["exemplar_features"]["computed"] == 0
    assert again["pairs"]["full"] == again["pairs"]["incremental"] == again["pairs"]["pairs_written"] == 0

    # a new shape: only its sweep is described, old exemplars are searched against it alone
    def rows() -> dict[int, list[tuple[int, int, Any]]]:
        with session_scope(db_url) as session:
            out: dict[int, list[tuple[int, int, Any]]] = {}
            for r in session.execute(sa.select(m.ExemplarMatch).order_by(m.ExemplarMatch.rank)).scalars():
                out.setdefault(r.exemplar_id, []).append((r.created_at, r.shape_id, r.searched_at))
            return out

    old_rows = rows()
    sid["s3"] = add_shape(db_url, store, "s3", chair(0.4, True, 0.3))
    third = run_coarse_alignment(config=CONFIG, renderer=renderer)
    assert third["view_features"]["computed"] == 1
    assert third["pairs"]["full"] == 0 and third["pairs"]["incremental"] == 2
    for eid, now in rows().items():  # every list was searched; only changed ones were rewritten
        same = [r[1] for r in now] == [r[1] for r in old_rows[eid]]
        assert ({r[0] for r in now} == {r[0] for r in old_rows[eid]}) == same
        assert all(n[2] > o[2] for n, o in zip(now, old_rows[eid], strict=False))
    # a new exemplar: searched against every shape, nobody else
    e2 = add_exemplar(db_url, store, "e2", SHAPES["s2"], view=30)
    fourth = run_coarse_alignment(config=CONFIG, renderer=renderer)
    assert fourth["exemplar_features"]["computed"] == 1
    assert fourth["pairs"]["full"] == 1 and fourth["pairs"]["incremental"] == 0
    with session_scope(db_url) as session:
        index = load_reverse_index(session, CONFIG)
    assert {e: [int(s) for s in a[:, 0]] for e, a in index.items()} == reference_lists(db_url, store, CONFIG)
    assert index[e2][0, 0] == sid["s2"]

    # excluding a shape drops its pairs (kept, excluded) and re-searches the exemplars that listed it
    with session_scope(db_url) as session:
        session.execute(sa.update(m.Shape).where(m.Shape.id == sid["s0"]).values(exclude=True))
    run_coarse_alignment(config=CONFIG, renderer=renderer)
    with session_scope(db_url) as session:
        pairs = session.execute(sa.select(m.Pair).where(m.Pair.shape_id == sid["s0"])).scalars().all()
        assert pairs and all(p.exclude and p.exclude_reason == DROPPED_REASON for p in pairs)
        index = load_reverse_index(session, CONFIG)
        assert sid["s0"] not in index[e0][:, 0]
        listed = session.execute(sa.select(sa.func.count(sa.distinct(m.ExemplarMatch.exemplar_id)))).scalar_one()
        assert listed == 3
    assert {e: [int(s) for s in a[:, 0]] for e, a in index.items()} == reference_lists(db_url, store, CONFIG)
    # and bringing it back restores its pairs without adding rows
    n = counts(db_url)
    with session_scope(db_url) as session:
        session.execute(sa.update(m.Shape).where(m.Shape.id == sid["s0"]).values(exclude=False))
    run_coarse_alignment(config=CONFIG, renderer=renderer)
    assert counts(db_url) == n
    with session_scope(db_url) as session:
        p = session.execute(
            sa.select(m.Pair).where(m.Pair.shape_id == sid["s0"], m.Pair.exemplar_id == e0)
        ).scalar_one()
        assert not p.exclude and p.rank == 1


def test_list_that_lost_rows_to_a_deleted_shape_is_searched_again(stage_db: str, store) -> None:  # type: ignore[no-untyped-def]
    db_url = stage_db
    renderer = NumpyRenderer()
    sid = {k: add_shape(db_url, store, k, mesh) for k, mesh in SHAPES.items()}
    e0 = add_exemplar(db_url, store, "e0", SHAPES["s0"], view=4)
    run_coarse_alignment(config=CONFIG, renderer=renderer)
    with session_scope(db_url) as session:
        second = int(load_reverse_index(session, CONFIG)[e0][1, 0])
        session.execute(sa.delete(m.Shape).where(m.Shape.id == second))  # cascades its index rows
        assert len(load_reverse_index(session, CONFIG)[e0]) == 1
    again = run_coarse_alignment(config=CONFIG, renderer=renderer)
    assert again["pairs"]["full"] == 1 and again["pairs"]["incremental"] == 0
    with session_scope(db_url) as session:
        index = load_reverse_index(session, CONFIG)
        ranks = session.execute(
            sa.select(m.ExemplarMatch.rank).where(m.ExemplarMatch.exemplar_id == e0).order_by(m.ExemplarMatch.rank)
        ).scalars().all()
    assert ranks == [1, 2] and second not in index[e0][:, 0]
    assert {e: [int(s) for s in a[:, 0]] for e, a in index.items()} == reference_lists(db_url, store, CONFIG)
    assert set(sid.values()) - {second} == {int(s) for s in index[e0][:, 0]}


def test_evaluate_against_ground_truth(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    renderer = NumpyRenderer()
    for k in ("s0", "s1"):
        add_shape(db_url, store, k, SHAPES[k])
    add_exemplar(db_url, store, "e0", SHAPES["s0"], view=4)
    add_exemplar(db_url, store, "e1", SHAPES["s1"], view=17)
    add_exemplar(db_url, store, "e2", SHAPES["s2"], view=8)  # its shape is not in the collection
    run_coarse_alignment(config=CONFIG, renderer=renderer)
    cams = viewpoints(VP)
    truth = {
        "e0": {"shape": "s0", "in_collection": True,
               "camera": cams[4].replace(azimuth=cams[4].azimuth + 0.035).to_dict()},
        "e1": {"shape": "s1", "in_collection": True, "camera": cams[17].to_dict()},
        "e2": {"shape": "s2", "in_collection": False, "camera": cams[8].to_dict()},
        "missing": {"shape": "s0", "in_collection": True, "camera": cams[0].to_dict()},
    }
    with session_scope(db_url) as session:
        metrics = evaluate_coarse_alignment(session, truth, config=CONFIG, renderer=renderer)
    assert metrics["n_in_collection"] == 2 and metrics["recall@1"] == 1.0 and metrics["recall@5"] == 1.0
    assert metrics["median_azimuth_error_deg"] == pytest.approx(1.0, abs=0.1)  # 0.035 rad off the grid
    assert metrics["median_elevation_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert metrics["n_nearest"] == 1 and 0.0 < metrics["mean_iou_nearest"] <= 1.0
    assert metrics["mean_iou_in_collection"] > 0.8
    # the demo's typed ground truth works the same way
    typed = SimpleNamespace(exemplars={
        "e1": SimpleNamespace(shape="s1", in_collection=True, camera=SimpleNamespace(**truth["e1"]["camera"])),
    })
    with session_scope(db_url) as session:
        again = evaluate_coarse_alignment(session, typed, config=CONFIG, renderer=renderer)
    assert again["n_in_collection"] == 1 and again["recall@1"] == 1.0
    assert again["median_azimuth_error_deg"] == pytest.approx(0.0, abs=1e-6)
