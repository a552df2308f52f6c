"""Shape ingest end to end: rows, parts, blobs, idempotence, replacement, bad input, catalogs, crashes."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from tests.geometry.makers import chair_members, write_chair_obj, write_glb, write_sh3f, write_shapenet_tree

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.ingest.ingest import IngestLimits, ingest_shapes, split_for

SH3D_CHAIR = {"id": "T#chair", "name": "Chair", "category": "Living room", "tags": "", "creator": "X",
              "model": "/t/chair/chair.obj"}
SH3D_LAMP = {"id": "T#lamp", "name": "Lamp", "category": "Lights", "tags": "", "model": "/t/lamp/chair.obj"}


def _shapes(url: str) -> dict[str, m.Shape]:
    with session_scope(url) as session:
        rows = session.execute(sa.select(m.Shape)).scalars().all()
        return {r.source_id: r for r in rows}


def test_ingest_writes_shape_parts_and_blobs(db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    write_chair_obj(tmp_path / "in", with_texture=True)
    summary = ingest_shapes([tmp_path / "in"], category="chair", license="CC0-1.0", isolate=False)
    assert len(summary.added) == 1 and not summary.rejected
    shape = _shapes(db_url)["chair"]
    assert (shape.source, shape.category, shape.status, shape.num_parts) == ("local", "chair", "ok", 3)
    assert shape.split == split_for("local", "chair") and shape.license == "CC0-1.0"
    assert shape.sha256 and shape.params_hash and shape.meta["groups"] == ["Legs", "Seat", "Back"]
    mesh = ShapeMesh.from_npz_bytes(store.read_bytes(shape.mesh_blob))
    assert mesh.num_faces == shape.num_faces
    with session_scope(db_url) as session:
        query = sa.select(m.Part).where(m.Part.shape_id == shape.id).order_by(m.Part.index)
        parts = session.execute(query).scalars().all()
        assert [(p.index, p.name) for p in parts] == [(1, "legs"), (2, "seat"), (3, "back")]
        seat = parts[1]
        assert seat.uv_density == pytest.approx(seat.area_uv / seat.area_world)
        assert seat.builtin_material["albedo"] == [0.8, 0.2, 0.1]
        assert store.exists(seat.builtin_material["texture"])  # map_Kd stored as a blob ref
        assert parts[0].builtin_material["roughness"] == pytest.approx(np.sqrt(2 / 102))
        assert "texture" not in parts[0].builtin_material


def test_reingest_is_idempotent_and_new_content_replaces(db_url: str, tmp_path: Path) -> None:
    folder = tmp_path / "in"
    write_chair_obj(folder)
    first = ingest_shapes([folder], isolate=False)
    before = _shapes(db_url)["chair"]
    again = ingest_shapes([folder], isolate=False)
    assert again.present == first.added and not again.added and not again.replaced
    same = _shapes(db_url)["chair"]
    assert (same.updated_at, same.mesh_blob) == (before.updated_at, before.mesh_blob)

    # derived rows that must disappear when the geometry changes
    with session_scope(db_url) as session:
        part_id = session.execute(sa.select(m.Part.id).where(m.Part.shape_id == before.id)).scalars().first()
        exemplar = m.Exemplar(source="t", source_id="e")
        vset = m.ViewpointSet(name="v", num_views=1, cameras=[[0, 0, 2, 50]])
        session.add_all([exemplar, vset])
        session.flush()
        pair = m.Pair(shape_id=before.id, exemplar_id=exemplar.id, rank=1, distance=1.0, azimuth=0, elevation=0,
                      fov=50, camera_distance=2)
        session.add(pair)
        session.add(m.ViewFeature(shape_id=before.id, viewpoint_set_id=vset.id, descriptor="hog"))
        session.flush()
        session.add(m.PartSubstance(pair_id=pair.id, part_id=part_id, substance="wood"))
        session.add(m.Rendering(kind="builtin", key="k", shape_id=before.id))

    write_chair_obj(folder, seat_kd="0.1 0.9 0.1")  # the MTL changes: new content
    replaced = ingest_shapes([folder], isolate=False)
    assert replaced.replaced == [before.id]
    after = _shapes(db_url)["chair"]
    assert after.id == before.id and after.sha256 != before.sha256 and after.params_hash != before.params_hash
    with session_scope(db_url) as session:
        for model in (m.Pair, m.ViewFeature, m.PartSubstance, m.Rendering):
            assert session.execute(sa.select(sa.func.count()).select_from(model)).scalar_one() == 0, model
        seat = session.execute(sa.select(m.Part).where(m.Part.shape_id == after.id, m.Part.index == 2)).scalar_one()
        assert seat.builtin_material["albedo"] == [0.1, 0.9, 0.1]


def test_bad_inputs_are_recorded_and_the_batch_goes_on(db_url: str, tmp_path: Path) -> None:
    folder = tmp_path / "in"
    write_chair_obj(folder)
    (folder / "empty.obj").write_bytes(b"")
    (folder / "nan.obj").write_text("v 0 0 0\nv nan 1 0\nv 0 1 0\nf 1 2 3\n")
    (folder / "truncated.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\nf 1 2 4\n")
    (folder / "binary.obj").write_bytes(bytes(range(256)) * 4)
    (folder / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    (folder / "corrupt.glb").write_bytes(b"glTF\x02\x00\x00\x00\xff\xff")
    big = write_chair_obj(tmp_path / "big", "huge")
    big.write_text(big.read_text() + "# padding\n" * 2000)
    limit = (folder / "chair.obj").stat().st_size + 100
    summary = ingest_shapes([folder, big, tmp_path / "missing.obj"], isolate=False,
                            limits=IngestLimits(max_shape_bytes=limit))
    assert len(summary.added) == 1  # the good chair
    reasons = {Path(k).name: v for k, v in summary.rejected}
    assert "no faces" in reasons["empty.obj"]
    assert "non-finite" in reasons["nan.obj"]
    assert "refers to vertex 4" in reasons["truncated.obj"]
    assert "binary content" in reasons["binary.obj"]
    assert "degenerate" in reasons["flat.obj"]
    assert "unreadable glTF" in reasons["corrupt.glb"]
    assert f"limit {limit}" in reasons["huge.obj"]
    assert "no such file" in reasons["missing.obj"]
    rows = _shapes(db_url)
    for name in ("empty", "nan", "truncated", "binary", "flat", "corrupt", "huge"):
        assert rows[name].status == "rejected" and rows[name].error and rows[name].mesh_blob is None, name
    with session_scope(db_url) as session:
        part_shapes = set(session.execute(sa.select(m.Part.shape_id)).scalars())
    assert part_shapes == {rows["chair"].id}  # rejected shapes have no parts
    # re-ingest: same rejections, no row changes
    stamp = rows["nan"].updated_at
    ingest_shapes([folder / "nan.obj"], isolate=False)
    assert _shapes(db_url)["nan"].updated_at == stamp


def test_face_limit_rejects_and_a_higher_limit_retries(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "in")
    summary = ingest_shapes([tmp_path / "in"], isolate=False, limits=IngestLimits(max_faces=20))
    assert "more than 20 faces" in summary.rejected[0][1]
    assert _shapes(db_url)["chair"].status == "rejected"
    summary = ingest_shapes([tmp_path / "in"], isolate=False)  # rejected rows are retried
    assert len(summary.added) == 1 and _shapes(db_url)["chair"].status == "ok"


def test_unreadable_file(db_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    obj = write_chair_obj(tmp_path / "in")
    real = Path.read_bytes

    def deny(self: Path) -> bytes:
        if self.name == "chair.obj":
            raise PermissionError(13, "Permission denied")
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", deny)
    summary = ingest_shapes([obj], isolate=False)
    assert "unreadable" in summary.rejected[0][1] and "Permission denied" in summary.rejected[0][1]
    assert _shapes(db_url)["chair"].status == "rejected"


def test_glb_shapenet_and_catalog_sources(db_url: str, tmp_path: Path) -> None:
    write_glb(tmp_path / "glb" / "stool.glb")
    write_shapenet_tree(tmp_path / "shapenet", "04256520", "s1")
    members = {**chair_members("t/chair"), **chair_members("t/lamp")}
    write_sh3f(tmp_path / "cat" / "Test.sh3f", [SH3D_CHAIR, SH3D_LAMP], members)
    summary = ingest_shapes([tmp_path / "glb", tmp_path / "shapenet", tmp_path / "cat"], isolate=False,
                            category="chair,sofa")
    assert len(summary.added) == 3 and not summary.rejected
    rows = _shapes(db_url)
    assert rows["stool"].num_parts == 2 and rows["stool"].meta["source_format"] == "glb"
    assert (rows["04256520/s1"].source, rows["04256520/s1"].category) == ("shapenet", "sofa")
    catalog = rows["Test/T#chair"]
    assert catalog.source == "sweethome3d" and catalog.category == "chair"
    assert catalog.source_path.endswith("Test.sh3f!t/chair/chair.obj")
    assert "Test/T#lamp" not in rows  # filtered out by category


def test_duplicate_stems_in_one_batch(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "a")
    write_chair_obj(tmp_path / "b")
    summary = ingest_shapes([tmp_path / "a", tmp_path / "b"], isolate=False)
    assert len(summary.added) == 1
    assert "already used" in summary.rejected[0][1]
    shutil.rmtree(tmp_path / "b")


def test_split_override_and_determinism(db_url: str, tmp_path: Path) -> None:
    ids = [f"chair{i}" for i in range(200)]
    splits = [split_for("local", i) for i in ids]
    assert splits == [split_for("local", i) for i in ids]
    assert 8 <= splits.count("val") <= 35
    write_chair_obj(tmp_path / "in")
    ingest_shapes([tmp_path / "in"], split="val", isolate=False)
    assert _shapes(db_url)["chair"].split == "val"


def test_isolated_importer_crash_is_recorded_as_failed(db_url: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    from tests.geometry.makers import crash_process

    import photoshape_flow.ingest.shapes as module

    write_chair_obj(tmp_path / "in")
    monkeypatch.setattr(module, "prepare_shape", crash_process)
    summary = ingest_shapes([tmp_path / "in"], isolate=True)
    assert summary.rejected and "crashed" in summary.rejected[0][1]
    row = _shapes(db_url)["chair"]
    assert row.status == "failed" and "SIGSEGV" in row.error


def test_isolated_ingest_of_a_real_shape(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "in")
    summary = ingest_shapes([tmp_path / "in"], isolate=True)
    assert len(summary.added) == 1


@pytest.mark.realdata
def test_real_models(db_url: str, shared_data: Path) -> None:
    summary = ingest_shapes([shared_data / "models"], isolate=False)
    assert len(summary.added) == 6 and not summary.rejected
    rows = _shapes(db_url)
    chair = rows["sweethome3d/chair2"]  # ids are paths relative to the folder given
    assert chair.num_parts == 2 and chair.meta["groups"] == ["Seat", "Back", "Feet"]
    assert rows["polyhaven_sofa_03/sofa_03_1k"].num_parts == 2


SH3F = Path("/usr/share/sweethome3d/furniture/KatorLegaz.sh3f")


@pytest.mark.realdata
@pytest.mark.skipif(not SH3F.is_file(), reason="Debian package sweethome3d-furniture is not installed")
def test_kator_legaz_chairs_that_crash_other_importers(db_url: str) -> None:
    # cafe-chair and office-chair contain 2-vertex "faces" (edges) that crash Blender's importer
    summary = ingest_shapes([SH3F], name_filter=r"^Kator Legaz#(cafe-chair|office-chair)$", isolate=True)
    assert len(summary.added) == 2 and not summary.rejected
    assert any("fewer than 3 vertices" in w for _, w in summary.warnings)
    rows = _shapes(db_url)
    assert rows["KatorLegaz/Kator Legaz#cafe-chair"].category == "chair"
    assert rows["KatorLegaz/Kator Legaz#cafe-chair"].license.startswith("Creative Commons")


def test_folder_per_model_trees_ingest_without_collisions(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "shapes" / "a")
    write_chair_obj(tmp_path / "shapes" / "b", seat_kd="0.1 0.2 0.8")
    summary = ingest_shapes([tmp_path / "shapes"], isolate=False)
    assert len(summary.added) == 2 and not summary.rejected, summary.rejected
    rows = _shapes(db_url)
    assert set(rows) == {"a/chair", "b/chair"} and {r.name for r in rows.values()} == {"chair"}
    # two identical files in two folders are two shapes as well, neither takes the other's row
    write_chair_obj(tmp_path / "shapes" / "c")
    again = ingest_shapes([tmp_path / "shapes"], isolate=False)
    assert len(again.added) == 1 and len(again.present) == 2 and set(_shapes(db_url)) == {"a/chair", "b/chair",
                                                                                           "c/chair"}


def test_reingest_renames_rows_stored_under_the_former_stem_id(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "shapes" / "a")
    write_chair_obj(tmp_path / "shapes" / "b", seat_kd="0.1 0.2 0.8")
    ingest_shapes([tmp_path / "shapes" / "a" / "chair.obj"], isolate=False)  # a file given by itself: its stem
    before = _shapes(db_url)["chair"]
    summary = ingest_shapes([tmp_path / "shapes"], isolate=False)  # by its recorded source_path
    rows = _shapes(db_url)
    assert set(rows) == {"a/chair", "b/chair"} and rows["a/chair"].id == before.id
    assert summary.present == [before.id] and len(summary.added) == 1
    assert rows["a/chair"].mesh_blob == before.mesh_blob  # unchanged content: not re-processed

    # moved, same content: found by (source, sha256) under its former id
    with session_scope(db_url) as session:
        session.execute(sa.update(m.Shape).where(m.Shape.id == before.id)
                        .values(source_id="chair", source_path="/gone/chair.obj"))
    summary = ingest_shapes([tmp_path / "shapes"], isolate=False)
    assert set(_shapes(db_url)) == {"a/chair", "b/chair"} and before.id in summary.present and not summary.added


def test_a_shape_the_database_refuses_fails_alone(db_url: str, tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """A row the database refuses (a NaN area became NULL in a NOT NULL column) fails that shape with one
    line; the shapes after it are ingested and nothing of it is half-written."""
    import photoshape_flow.ingest.shapes as ingest_module

    real = ingest_module._part_rows
    calls: list[int] = []

    def refused(shape_id, prepared):  # type: ignore[no-untyped-def]
        rows = real(shape_id, prepared)
        if not calls:  # the first shape stored: a.obj (files are taken in name order)
            rows[0]["area_uv"] = float("nan")
        calls.append(shape_id)
        return rows

    monkeypatch.setattr(ingest_module, "_part_rows", refused)
    write_chair_obj(tmp_path / "in", "a")
    write_chair_obj(tmp_path / "in", "b")
    summary = ingest_shapes([tmp_path / "in"], isolate=False)
    shapes = _shapes(db_url)
    assert shapes["a"].status == "failed" and "could not store it" in shapes["a"].error
    assert shapes["b"].status == "ok" and len(summary.added) == 1
    with session_scope(db_url) as session:
        assert session.execute(sa.select(sa.func.count()).select_from(m.Part)
                               .where(m.Part.shape_id == shapes["a"].id)).scalar_one() == 0


def test_a_catalog_texture_with_an_authoring_machine_path_is_found_next_to_the_model(
        db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """9 of 826 Sweet Home 3D models were refused for an MTL line like `map_Kd C:/Documents and
    Settings/.../wood.jpg`: the path is never followed, the file of that name beside the model is used."""
    import cv2

    members = chair_members("t/chair")
    mtl = members["t/chair/chair.mtl"].decode()
    members["t/chair/chair.mtl"] = mtl.replace("newmtl seat", "newmtl seat\nmap_Kd C:/Users/me/Desktop/wood.jpg", 1)\
        .encode()
    members["t/chair/wood.jpg"] = cv2.imencode(".jpg", np.full((8, 8, 3), 90, np.uint8))[1].tobytes()
    write_sh3f(tmp_path / "cat" / "Test.sh3f", [SH3D_CHAIR], members)
    summary = ingest_shapes([tmp_path / "cat"], isolate=False)
    assert len(summary.added) == 1 and not summary.rejected, summary.rejected
    shape = _shapes(db_url)["Test/T#chair"]
    with session_scope(db_url) as session:
        seat = session.execute(sa.select(m.Part).where(m.Part.shape_id == shape.id, m.Part.name == "seat")
                               ).scalar_one()
        assert store.exists(seat.builtin_material["texture"])  # the texture beside the model
