"""Exemplar ingest: crops and masks stored, duplicates marked, idempotence, replacement, bad images."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from PIL import Image
from tests.imaging.test_exemplar import photo
from tests.imaging.test_io import png_declaring

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.imaging.dedupe import DESCRIPTOR
from photoshape_flow.ingest.ingest import ingest_exemplars


def _save(path: Path, array: np.ndarray, fmt: str = "JPEG", scale: float = 1.0) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    image = Image.fromarray(array)
    if scale != 1.0:
        image = image.resize((int(array.shape[1] * scale), int(array.shape[0] * scale)), Image.LANCZOS)
    image.save(path, fmt, **({"quality": 92} if fmt == "JPEG" else {}))
    return path


def _rows(url: str) -> dict[str, m.Exemplar]:
    with session_scope(url) as session:
        return {r.source_id: r for r in session.execute(sa.select(m.Exemplar)).scalars()}


def test_ingest_stores_crop_mask_and_feature(db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    _save(tmp_path / "in" / "a.jpg", photo(box=(100, 50, 160, 170)))
    _save(tmp_path / "in" / "b.png", photo(box=(20, 20, 280, 120), seed=5), "PNG")
    _save(tmp_path / "in" / "c.webp", photo(box=(30, 60, 200, 100), seed=7), "WEBP")
    summary = ingest_exemplars([tmp_path / "in"], size=64, category="chair", license="CC-BY-4.0")
    assert len(summary.added) == 3 and not summary.rejected and not summary.duplicates
    row = _rows(db_url)["a"]
    assert (row.status, row.size, row.native_width, row.native_height) == ("ok", 64, 300, 200)
    assert row.meta["crop"] == {"x0": 70, "y0": 50, "side": 120}
    assert row.category == "chair" and row.license == "CC-BY-4.0" and row.sha256
    assert store.load_image(row.image_blob).shape == (64, 64, 3)
    mask = store.load_image(row.mask_blob)
    assert mask.shape == (64, 64) and set(np.unique(mask)) <= {0, 255}
    with session_scope(db_url) as session:
        query = sa.select(m.ExemplarFeature).where(m.ExemplarFeature.exemplar_id == row.id)
        feature = session.execute(query).scalar_one()
    assert feature.descriptor == DESCRIPTOR and store.load_array(feature.feature_blob).shape == (441,)


def test_duplicates_within_a_batch_and_against_the_database(db_url: str, tmp_path: Path) -> None:
    original = photo(box=(100, 50, 160, 170))
    _save(tmp_path / "first" / "orig.jpg", original)
    ingest_exemplars([tmp_path / "first"])
    _save(tmp_path / "second" / "copy_big.jpg", original, scale=1.25)
    _save(tmp_path / "second" / "other.jpg", photo(box=(20, 20, 280, 120), seed=5))
    _save(tmp_path / "second" / "other_copy.png", photo(box=(20, 20, 280, 120), seed=5), "PNG")
    summary = ingest_exemplars([tmp_path / "second"])
    rows = _rows(db_url)
    assert len(summary.added) == 3
    assert (rows["copy_big"].duplicate_of_id, rows["copy_big"].exclude) == (rows["orig"].id, True)
    assert "duplicate of exemplar" in rows["copy_big"].exclude_reason
    assert rows["other"].duplicate_of_id is None and not rows["other"].exclude
    assert rows["other_copy"].duplicate_of_id == rows["other"].id
    assert sorted(summary.duplicates) == sorted([(rows["copy_big"].id, rows["orig"].id),
                                                 (rows["other_copy"].id, rows["other"].id)])


def test_reingest_is_idempotent_and_changed_photo_replaces(db_url: str, tmp_path: Path) -> None:
    path = _save(tmp_path / "in" / "p.jpg", photo())
    first = ingest_exemplars([path])
    before = _rows(db_url)["p"]
    again = ingest_exemplars([path])
    assert again.present == first.added and _rows(db_url)["p"].updated_at == before.updated_at
    with session_scope(db_url) as session:
        shape = m.Shape(source="t", source_id="s")
        session.add(shape)
        session.flush()
        session.add(m.Pair(shape_id=shape.id, exemplar_id=before.id, rank=1, distance=1.0, azimuth=0,
                           elevation=0, fov=50, camera_distance=2))
    _save(path, photo(box=(20, 20, 280, 120), seed=9))
    replaced = ingest_exemplars([path])
    assert replaced.replaced == [before.id]
    after = _rows(db_url)["p"]
    assert after.sha256 != before.sha256 and after.image_blob != before.image_blob
    assert after.duplicate_of_id is None  # not a duplicate of its own old version
    with session_scope(db_url) as session:
        assert session.execute(sa.select(sa.func.count()).select_from(m.Pair)).scalar_one() == 0


def test_bad_images_are_rejected_rows(db_url: str, tmp_path: Path) -> None:
    folder = tmp_path / "in"
    _save(folder / "good.jpg", photo())
    (folder / "text.jpg").write_text("not an image at all")
    data = io.BytesIO()
    Image.fromarray(photo()).save(data, "JPEG")
    (folder / "truncated.jpg").write_bytes(data.getvalue()[:600])
    (folder / "bomb.png").write_bytes(png_declaring(60_000, 60_000))
    _save(folder / "blank.png", np.full((50, 50, 3), 255, np.uint8), "PNG")
    _save(folder / "dark.png", np.full((50, 50, 3), 20, np.uint8) + np.eye(50, dtype=np.uint8)[:, :, None] * 200,
          "PNG")
    (folder / "notes.txt").write_text("ignored: not an image suffix")
    (tmp_path / "x.gif").write_bytes(b"GIF89a")
    summary = ingest_exemplars([folder, tmp_path / "nope.jpg", tmp_path / "x.gif"])
    reasons = {Path(k).name: v for k, v in summary.rejected}
    assert len(summary.added) == 1
    assert "not an image" in reasons["text.jpg"]
    assert "truncated" in reasons["truncated.jpg"].lower()
    assert "bomb" in reasons["bomb.png"] or "exceeds" in reasons["bomb.png"]
    assert "no foreground" in reasons["blank.png"]
    assert "no white background" in reasons["dark.png"]
    assert "no such file" in reasons["nope.jpg"] and "unsupported file type" in reasons["x.gif"]
    rows = _rows(db_url)
    for name in ("text", "truncated", "bomb", "blank", "dark"):
        assert rows[name].status == "rejected" and rows[name].image_blob is None and rows[name].error, name
    assert "notes" not in rows


@pytest.mark.realdata
def test_real_abo_photos(db_url: str, shared_data: Path) -> None:
    summary = ingest_exemplars([shared_data / "photos" / "abo"], size=512, source="abo")
    assert len(summary.added) == 20 and not summary.rejected and not summary.duplicates
    rows = _rows(db_url)
    assert all(r.size <= 128 and r.native_width == 128 for r in rows.values())  # never upscaled


def test_source_ids_are_relative_paths_and_former_stem_rows_are_renamed(db_url: str, tmp_path: Path) -> None:
    first = _save(tmp_path / "in" / "a" / "chair.jpg", photo(box=(100, 50, 160, 170)))
    _save(tmp_path / "in" / "b" / "chair.jpg", photo(box=(20, 20, 280, 120), seed=5))
    ingest_exemplars([first], size=64)  # a file given by itself: its stem, as every id used to be
    before = _rows(db_url)["chair"]
    summary = ingest_exemplars([tmp_path / "in"], size=64)
    rows = _rows(db_url)
    assert set(rows) == {"a/chair", "b/chair"} and rows["a/chair"].id == before.id
    assert summary.present == [before.id] and len(summary.added) == 1 and not summary.duplicates
