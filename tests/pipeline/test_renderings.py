"""record_rendering: blobs by type, one row per (kind, key), idempotent."""

from __future__ import annotations

import numpy as np
import pytest
import sqlalchemy as sa

from photoshape_flow.db.models import Rendering
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.renderings import load_rendering_image, record_rendering, sniff_extension


def passes() -> dict[str, np.ndarray | bytes]:
    rng = np.random.default_rng(0)
    ids = np.zeros((12, 12), np.uint16)
    ids[2:6, 2:10] = 3
    ids[6:10, 2:10] = 1027  # beyond 8 bits: must survive exactly
    return {
        "srgb": rng.integers(0, 256, (12, 12, 3), dtype=np.uint8),
        "part_ids": ids,
        "hdr": rng.random((12, 12, 3), dtype=np.float32) * 4,
        "mask": ids > 0,
    }


def test_record_rendering_round_trip_and_idempotent(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    images = passes()
    params = {"camera": {"azimuth": 0.1, "elevation": 0.2, "distance": 2.0, "fov": 50.0}, "spp": 4}
    with session_scope(db_url) as session:
        first = record_rendering(
            session, store, kind="part-map", key="pair-1", images=images, params=params, split="train", seconds=0.5
        )
    with session_scope(db_url) as session:
        again = record_rendering(
            session, store, kind="part-map", key="pair-1", images=images, params=params, split="train", seconds=0.5
        )
    assert again == first
    with session_scope(db_url) as session:
        rows = session.execute(sa.select(Rendering)).scalars().all()
        assert len(rows) == 1
        row = rows[0]
        assert set(row.blobs) == {"srgb", "part_ids", "hdr", "mask"}
        assert row.blobs["part_ids"].endswith(".png") and row.blobs["hdr"].endswith(".exr")
        assert row.params == params and row.split == "train" and row.status == "ok"
        assert np.array_equal(load_rendering_image(store, row, "srgb"), images["srgb"])
        ids = load_rendering_image(store, row, "part_ids")
        assert ids.dtype == np.uint16 and np.array_equal(ids, images["part_ids"])
        hdr = load_rendering_image(store, row, "hdr")
        assert hdr.dtype == np.float32 and np.allclose(hdr, images["hdr"], rtol=1e-3, atol=1e-3)  # half floats
        assert np.array_equal(load_rendering_image(store, row, "mask") > 127, images["mask"])
        with pytest.raises(KeyError, match="no pass 'depth'"):
            load_rendering_image(store, row, "depth")


def test_record_rendering_updates_and_records_failures(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        rid = record_rendering(session, store, kind="training", key="t/1", images={}, params={}, status="failed",
                               error="envmap missing")
    png = store.read_bytes(store.put_image(np.zeros((4, 4, 3), np.uint8)))
    with session_scope(db_url) as session:
        again = record_rendering(session, store, kind="training", key="t/1", images={"srgb": png}, params={"spp": 8},
                                 saturated_fraction=0.01)
        row = session.get(Rendering, again)
        assert again == rid and row is not None
        assert row.status == "ok" and row.error is None and row.blobs["srgb"].endswith(".png")
        assert row.saturated_fraction == pytest.approx(0.01) and row.params == {"spp": 8}


def test_bad_input_is_rejected(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        with pytest.raises(ValueError, match="unknown rendering kind"):
            record_rendering(session, store, kind="nope", key="k", images={}, params={})
        with pytest.raises(ValueError, match="pass 'x'"):
            record_rendering(session, store, kind="preview", key="k", images={"x": np.zeros((4, 4), np.int64)},
                             params={})
    with pytest.raises(ValueError, match="unrecognised"):
        sniff_extension(b"GIF89a")
    assert sniff_extension(b"\xff\xd8\xff\xe0rest") == "jpg"
