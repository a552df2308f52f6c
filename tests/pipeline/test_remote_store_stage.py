"""A stage runs unchanged on a blob store at a URL: training renders with a file:// blob root.

The renderer reads envmaps through `resolve` (the cache) and every row's blobs land in the shared
store; a machine with an empty cache fetches them back, byte for byte.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from tests.synth.collection import seed_collection

from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.recognition.training_renders import run_training_renders
from photoshape_flow.store import BlobStore
from photoshape_flow.store.refs import ref_subpath


@pytest.mark.render
def test_training_renders_write_to_a_url_store(db_url: str, settings_env: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    shared = tmp_path / "shared-blobs"
    monkeypatch.setenv("PHOTOSHAPE_BLOB_ROOT", shared.as_uri())
    get_settings.cache_clear()
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    assert store.is_remote and settings.blob_cache_root == settings_env / "cache" / "blobs"
    with session_scope(db_url) as session:
        seed_collection(session, store, shape_splits=("train", "val"))

    summary = run_training_renders("bootstrap", count=2, size=24, spp=2)
    assert summary["rendered"] == 2 and summary["failed"] == 0
    with session_scope(db_url) as session:
        rows = list(session.execute(sa.select(m.Rendering)).scalars())
    refs = {ref for row in rows for ref in row.blobs.values()}
    assert len(rows) == 2 and refs
    assert all((shared / ref_subpath(ref)).is_file() for ref in refs)  # in the shared store
    assert not (settings_env / "blobs").exists()  # nothing went to the local default folder

    other_machine = BlobStore(settings.blob_root, cache_root=tmp_path / "other-cache")
    for ref in refs:
        assert other_machine.resolve(ref).read_bytes() == (shared / ref_subpath(ref)).read_bytes()
    beauty = rows[0].blobs["beauty"]
    assert other_machine.load_image(beauty).shape[:2] == (24, 24)
    assert np.array_equal(other_machine.load_image(beauty), store.load_image(beauty))
