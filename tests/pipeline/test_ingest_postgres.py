"""Ingest on PostgreSQL: upserts, replacement with dependent deletes, rejections and dedupe."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from tests.geometry.makers import write_chair_obj, write_png
from tests.imaging.test_exemplar import photo


@pytest.fixture
def pg_settings(pg_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db.session import get_engine

    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", str(tmp_path / "data"))
    monkeypatch.setenv("PHOTOSHAPE_DATABASE_URL", pg_url)
    get_settings.cache_clear()
    get_engine.cache_clear()
    migrate.upgrade(pg_url)
    yield pg_url
    get_engine(pg_url).dispose()
    get_settings.cache_clear()
    get_engine.cache_clear()


@pytest.mark.postgres
def test_ingest_on_postgres(pg_settings: str, tmp_path: Path) -> None:
    from photoshape_flow.ingest.ingest import ingest_exemplars, ingest_shapes

    write_chair_obj(tmp_path / "in")
    assert len(ingest_shapes([tmp_path / "in"], isolate=False).added) == 1
    write_chair_obj(tmp_path / "in", seat_kd="0 1 0")
    assert len(ingest_shapes([tmp_path / "in"], isolate=False).replaced) == 1
    (tmp_path / "in" / "bad.obj").write_text("v 0 0 0\n")
    summary = ingest_shapes([tmp_path / "in"], isolate=False)
    assert len(summary.present) == 1 and len(summary.rejected) == 1
    write_png(tmp_path / "p" / "a.png", photo())
    write_png(tmp_path / "p" / "b.png", photo())
    assert len(ingest_exemplars([tmp_path / "p"]).duplicates) == 1
    assert len(ingest_exemplars([tmp_path / "p"]).present) == 2


@pytest.mark.postgres
def test_text_postgres_cannot_store_is_one_rejected_line_each(pg_settings: str, tmp_path: Path) -> None:
    """A NUL, which PostgreSQL text and JSONB refuse, and a catalog id past String(255): before, the
    rejected catalog pieces' rows raised DataError outside the item guard and ended the batch."""
    from tests.geometry.makers import chair_members, write_sh3f

    from photoshape_flow.ingest.ingest import ingest_materials, ingest_shapes

    chair = {"id": "T#chair", "name": "Chair", "category": "Living room", "model": "/t/chair/chair.obj"}
    pieces = [chair, {**chair, "id": "T#nul", "name": "a\\u0000b", "model": "x.fbx"},
              {**chair, "id": "T#" + "i" * 300, "model": ""}]
    write_sh3f(tmp_path / "in" / "a_cat.sh3f", pieces, chair_members("t/chair"))
    write_chair_obj(tmp_path / "in" / "zz")
    summary = ingest_shapes([tmp_path / "in"], isolate=False)
    assert len(summary.added) == 2 and len(summary.rejected) == 2, summary.rejected
    assert {reason.split(" (")[0] for _, reason in summary.rejected} == {
        "name contains U+0000", "catalog id is 302 characters long"}
    for folder in ("wood_good", "a_bad"):
        write_png(tmp_path / "m" / folder / "albedo.png", np.full((4, 4, 3), 120, np.uint8))
    (tmp_path / "m" / "a_bad" / "material.json").write_text('{"substance": "wood", "params": {"x": "a\\u0000b"}}')
    summary = ingest_materials([tmp_path / "m"], previews=False)
    assert len(summary.added) == 1 and len(summary.rejected) == 1 and "U+0000" in summary.rejected[0][1]
