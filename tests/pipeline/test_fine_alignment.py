"""Fine alignment stage: rows and blobs per pair, idempotent re-runs, failures, evaluation.

A painter's-algorithm numpy rasteriser stands in for Mitsuba (one test uses the real renderer).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import sqlalchemy as sa

from photoshape_flow.align.fine import FineParams
from photoshape_flow.align.partmap import crop_square, square_box
from photoshape_flow.alignment.fine_alignment import (
    evaluate_fine_alignment,
    run_fine_alignment,
    truth_in_stored_frame,
)
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

SIZE = 64
PALETTE = np.array([[255, 255, 255], [150, 40, 30], [40, 60, 170], [30, 140, 60]], np.uint8)
PAIR_CAMERA = Camera(0.5, 0.3, 2.0, 50.0)
TRUE_CAMERA = Camera(0.75, 0.4, 1.6, 60.0)


class PainterRenderer:
    """Exact-enough part IDs by drawing projected triangles far to near (numpy + cv2 only)."""

    def __init__(self) -> None:
        self.calls = 0

    def part_ids(self, shape: ShapeMesh, camera: Camera, size: int = 256) -> np.ndarray:
        self.calls += 1
        faces = []
        for part in shape.parts:
            xy, depth = camera.project(part.vertices, size)
            for face in part.faces:
                faces.append((float(depth[face].mean()), xy[face], part.index))
        ids = np.zeros((size, size), np.uint16)
        for _, poly, index in sorted(faces, key=lambda f: -f[0]):
            cv2.fillConvexPoly(ids, np.round(poly * 16).astype(np.int32), int(index), lineType=cv2.LINE_8, shift=4)
        return ids


def chair_mesh() -> ShapeMesh:
    return normalise_to_unit_cube([
        box_part(1, (0.0, 0.0, 0.0), (0.5, 0.08, 0.45), "seat"),
        box_part(2, (0.0, 0.5, -0.4), (0.5, 0.45, 0.06), "back"),
        box_part(3, (0.0, -0.5, 0.0), (0.1, 0.45, 0.1), "post"),
    ])


def make_exemplar(store, renderer: PainterRenderer, shape: ShapeMesh, native: int = 200):  # type: ignore[no-untyped-def]
    """A 'photo' of the shape from TRUE_CAMERA, cropped like ingest crops; returns row values and the truth."""
    ids = renderer.part_ids(shape, TRUE_CAMERA, native)
    rgb = PALETTE[ids]
    rng = np.random.default_rng(0)
    rgb = np.clip(rgb + rng.normal(0, 3, rgb.shape), 0, 255).astype(np.uint8)
    rgb[ids == 0] = 255
    x0, y0, side = square_box(ids > 0)
    image = cv2.resize(crop_square(rgb, x0, y0, side, fill=255), (96, 96), interpolation=cv2.INTER_AREA)
    mask = cv2.resize(crop_square((ids > 0).astype(np.uint8) * 255, x0, y0, side), (96, 96),
                      interpolation=cv2.INTER_NEAREST)
    values = {
        "image_blob": store.put_image(image), "mask_blob": store.put_image(mask), "size": 96,
        "native_width": native, "native_height": native, "meta": {"crop": {"x0": x0, "y0": y0, "side": side}},
    }
    return values, ids


def seed_db(url: str, store, renderer: PainterRenderer) -> dict:  # type: ignore[no-untyped-def]
    shape = chair_mesh()
    exemplar_values, truth = make_exemplar(store, renderer, shape)
    with session_scope(url) as session:
        good = m.Shape(source="test", source_id="chair", mesh_blob=store.put_bytes(shape.to_npz_bytes(), "npz"))
        broken = m.Shape(source="test", source_id="broken", mesh_blob=None)
        other = m.Shape(source="test", source_id="other", mesh_blob=good.mesh_blob)
        session.add_all([good, broken, other])
        session.flush()
        for s in (good, other):
            session.add_all([m.Part(shape_id=s.id, index=p.index, name=p.name) for p in shape.parts])
        exemplar = m.Exemplar(source="test", source_id="photo_0001", **exemplar_values)
        session.add(exemplar)
        session.flush()
        camera = {"azimuth": PAIR_CAMERA.azimuth, "elevation": PAIR_CAMERA.elevation,
                  "camera_distance": PAIR_CAMERA.distance, "fov": PAIR_CAMERA.fov}
        pairs = {}
        for s in (good, broken, other):
            pair = m.Pair(shape_id=s.id, exemplar_id=exemplar.id, rank=1, distance=1.0, **camera)
            session.add(pair)
            session.flush()
            pairs[s.source_id] = pair.id
    return {"pairs": pairs, "truth": truth, "shape": shape}


def alignment_rows(url: str) -> list[m.Alignment]:
    with session_scope(url) as session:
        return list(session.execute(sa.select(m.Alignment).order_by(m.Alignment.pair_id)).scalars())


def test_run_is_idempotent_and_records_failures(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    renderer = PainterRenderer()
    seeded = seed_db(db_url, store, renderer)
    params = FineParams(size=SIZE)
    first = run_fine_alignment(settings=get_settings(), params=params, renderer=renderer)
    assert first["candidates"] == 3
    assert first["aligned"] == 2 and first["failed"] == 1
    assert "mesh_blob is missing" in first["failures"][0]["error"]
    rows = alignment_rows(db_url)
    assert len(rows) == 3
    by_pair = {r.pair_id: r for r in rows}
    good = by_pair[seeded["pairs"]["chair"]]
    assert good.status == "ok" and good.error is None and good.method == "flow-crf"
    assert good.params["size"] == SIZE and good.params["flow"]["method"] and good.seconds is not None
    for name in ("coarse", "flow", "crf"):
        labels = store.load_image(getattr(good, f"{name}_blob"))
        assert labels.dtype == np.uint16 and labels.shape == (SIZE, SIZE)
        assert set(np.unique(labels)) <= {0, 1, 2, 3}
    assert good.iou_flow > good.iou_coarse
    broken = by_pair[seeded["pairs"]["broken"]]
    assert broken.status == "failed" and "mesh_blob" in broken.error and broken.crf_blob is None

    calls = renderer.calls
    again = run_fine_alignment(settings=get_settings(), params=params, renderer=renderer)
    assert again["aligned"] == 0 and again["failed"] == 0 and again["up_to_date"] == 3
    assert renderer.calls == calls
    assert [(r.id, r.params_hash, r.crf_blob) for r in alignment_rows(db_url)] == [
        (r.id, r.params_hash, r.crf_blob) for r in rows
    ]

    retried = run_fine_alignment(settings=get_settings(), params=params, renderer=renderer, retry_failed=True)
    assert retried["aligned"] == 0 and retried["failed"] == 1

    # changed settings make every row stale: recomputed in place, no new rows
    changed = run_fine_alignment(settings=get_settings(), params=FineParams(size=48), renderer=renderer,
                                 pair_ids=[seeded["pairs"]["chair"]])
    assert changed["candidates"] == 1 and changed["aligned"] == 1
    rows_after = alignment_rows(db_url)
    assert len(rows_after) == 3
    assert store.load_image({r.pair_id: r for r in rows_after}[seeded["pairs"]["chair"]].crf_blob).shape == (48, 48)


def test_excluded_pairs_are_skipped(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    renderer = PainterRenderer()
    seeded = seed_db(db_url, store, renderer)
    with session_scope(db_url) as session:
        session.execute(sa.update(m.Pair).where(m.Pair.id != seeded["pairs"]["chair"]).values(exclude=True))
    summary = run_fine_alignment(settings=get_settings(), params=FineParams(size=SIZE), renderer=renderer)
    assert summary["candidates"] == 1 and summary["aligned"] == 1


def test_evaluate_scores_exact_pairs_and_writes_accuracy(db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    renderer = PainterRenderer()
    seeded = seed_db(db_url, store, renderer)
    run_fine_alignment(settings=get_settings(), params=FineParams(size=SIZE), renderer=renderer)
    # ground truth as the demo writes it: native-frame mask with its own values and a name table
    native = seeded["truth"]
    remap = np.array([0, 7, 5, 9], np.uint8)  # values in the mask are not the shape's part indices
    mask_path = tmp_path / "photo_0001.mask.png"
    cv2.imwrite(str(mask_path), remap[native])
    truth = {"photo_0001": {"shape": "chair", "in_collection": True, "mask": str(mask_path),
                            "part_names": {"7": "seat", "5": "back", "9": "post"}}}
    with session_scope(db_url) as session:
        result = evaluate_fine_alignment(session, truth, settings=get_settings())
    assert result["n_exact"] == 1 and result["n_other"] == 1
    assert 0.0 <= result["accuracy_coarse"] < result["accuracy_flow"] <= 1.0
    assert result["accuracy_crf"] > 0.9
    assert result["flow_improves"] is True
    good = {r.pair_id: r for r in alignment_rows(db_url)}[seeded["pairs"]["chair"]]
    assert good.accuracy_crf == pytest.approx(result["accuracy_crf"])
    assert good.accuracy_coarse == pytest.approx(result["accuracy_coarse"])
    other = {r.pair_id: r for r in alignment_rows(db_url)}[seeded["pairs"]["other"]]
    assert other.accuracy_crf is None
    assert result["iou_other_crf"] == pytest.approx(other.iou_crf)


def test_truth_in_stored_frame_maps_names_and_crop() -> None:
    native = np.zeros((10, 12), np.uint8)
    native[2:6, 3:9] = 4
    native[6:8, 3:9] = 2
    out = truth_in_stored_frame(native, {"x0": 3, "y0": 1, "side": 8}, {4: "seat", 2: "nothing"}, {"seat": 1}, 8)
    assert out.dtype == np.uint16 and out.shape == (8, 8)
    assert (out[1:5, 0:6] == 1).all()
    assert (out[5:7, 0:6] == 65535).all()  # a part name the shape lacks never counts as right
    assert not out[0].any() and not out[:, 6:].any()


@pytest.mark.render
def test_run_with_the_mitsuba_renderer(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("mitsuba")
    from photoshape_flow.render.renderer import Renderer

    seeded = seed_db(db_url, store, PainterRenderer())
    summary = run_fine_alignment(pair_ids=[seeded["pairs"]["chair"]], settings=get_settings(),
                                 params=FineParams(size=SIZE), renderer=Renderer())
    assert summary["aligned"] == 1, summary
    (row,) = [r for r in alignment_rows(db_url) if r.pair_id == seeded["pairs"]["chair"]]
    assert row.iou_crf > 0.8 and row.iou_flow > row.iou_coarse - 0.01
    assert not math.isnan(row.seconds)
