"""Shared fixtures: an isolated data root and migrated SQLite database per test, real data location."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, or skip the test when this checkout has none beside it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def settings_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Point PHOTOSHAPE_DATA_ROOT at a fresh folder with its own SQLite database."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import get_engine

    data_root = tmp_path / "data"
    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", str(data_root))
    monkeypatch.delenv("PHOTOSHAPE_DATABASE_URL", raising=False)
    get_settings.cache_clear()
    get_engine.cache_clear()
    yield data_root
    get_settings.cache_clear()
    get_engine.cache_clear()


@pytest.fixture
def db_url(settings_env: Path) -> str:
    """A migrated SQLite database under the test's data root; returns its URL."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate

    url = get_settings().resolved_database_url
    migrate.upgrade(url)
    return url


@pytest.fixture
def store(settings_env: Path):  # type: ignore[no-untyped-def]
    from photoshape_flow.config import get_settings
    from photoshape_flow.store import BlobStore

    return BlobStore(get_settings().blob_root)
