"""Ingest on PostgreSQL: upserts, replacement with dependent deletes, rejections and dedupe."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

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
