"""Settings come from PHOTOSHAPE_* variables with safe defaults."""

from __future__ import annotations

from pathlib import Path

import pytest

from photoshape_flow.config import Settings


def test_defaults_put_sqlite_under_the_data_root(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("PHOTOSHAPE_DATABASE_URL", raising=False)
    monkeypatch.delenv("PHOTOSHAPE_DATA_ROOT", raising=False)
    settings = Settings(_env_file=None)
    assert settings.data_root == Path("photoshape-data")
    assert settings.resolved_database_url.startswith("sqlite:///")
    assert settings.resolved_database_url.endswith("photoshape-data/photoshape.db")


def test_environment_overrides_and_postgres_urls_are_normalised(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", "/srv/ps")
    monkeypatch.setenv("PHOTOSHAPE_DATABASE_URL", "postgres://u@db:5432/ps")
    settings = Settings(_env_file=None)
    assert settings.data_root == Path("/srv/ps")
    assert settings.resolved_database_url == "postgresql+psycopg://u@db:5432/ps"


def test_render_threads_never_below_two(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PHOTOSHAPE_RENDER_THREADS", "1")
    assert Settings(_env_file=None).effective_render_threads == 2


def test_blob_root_is_a_folder_under_the_data_root_or_a_url(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", "/srv/ps")
    monkeypatch.delenv("PHOTOSHAPE_BLOB_ROOT", raising=False)
    settings = Settings(_env_file=None)
    assert settings.blob_root == Path("/srv/ps/blobs") and settings.blob_cache_root == Path("/srv/ps/cache/blobs")
    monkeypatch.setenv("PHOTOSHAPE_BLOB_ROOT", "s3://bucket/photoshape/blobs")
    assert Settings(_env_file=None).blob_root == "s3://bucket/photoshape/blobs"  # fsspec parses the URL
    monkeypatch.setenv("PHOTOSHAPE_BLOB_ROOT", "/mnt/shared/blobs")
    assert Settings(_env_file=None).blob_root == Path("/mnt/shared/blobs")
