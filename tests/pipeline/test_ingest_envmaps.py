"""Envmap ingest: validation, blobs byte for byte, deterministic split with both splits populated."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from tests.imaging.test_hdr import sky, write_exr, write_hdr

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.ingest.envmaps import envmap_split
from photoshape_flow.ingest.ingest import ingest_envmaps


def _rows(url: str) -> dict[str, m.Envmap]:
    with session_scope(url) as session:
        return {r.name: r for r in session.execute(sa.select(m.Envmap)).scalars()}


def test_ingest_validates_stores_and_splits(db_url: str, store, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    folder = tmp_path / "env"
    folder.mkdir()
    for i in range(5):
        write_hdr(folder / f"studio_{i}.hdr", sky() * (i + 1))
    write_exr(folder / "night.exr", sky() * 0.1)
    write_exr(folder / "nan.exr", np.full((32, 64, 3), np.nan, np.float32))
    write_hdr(folder / "square.hdr", sky(64, 64))
    (folder / "junk.hdr").write_bytes(b"nope")
    summary = ingest_envmaps([folder], license="CC0-1.0", isolate=False)
    assert len(summary.added) == 6
    reasons = {Path(k).name: v for k, v in summary.rejected}
    assert "non-finite" in reasons["nan.exr"] and "not 2:1" in reasons["square.hdr"]
    assert "bad magic" in reasons["junk.hdr"]
    rows = _rows(db_url)
    ok = {n: r for n, r in rows.items() if r.status == "ok"}
    assert {r.split for r in ok.values()} == {"train", "val"}  # both splits have lighting
    night = rows["night"]
    assert store.read_bytes(night.blob) == (folder / "night.exr").read_bytes() and night.blob.endswith(".exr")
    assert (night.width, night.height, night.license) == (64, 32, "CC0-1.0")
    assert rows["nan"].status == "rejected" and not rows["nan"].enabled and rows["nan"].blob is None
    # deterministic: the same names get the same splits in a fresh database
    splits = {n: r.split for n, r in ok.items()}
    again = ingest_envmaps([folder], isolate=False)
    assert len(again.present) == 6 and {n: r.split for n, r in _rows(db_url).items() if r.status == "ok"} == splits


def test_split_override_and_hash_split(db_url: str, tmp_path: Path) -> None:
    names = [f"env_{i}" for i in range(300)]
    assert 10 <= sum(envmap_split(n) == "val" for n in names) <= 50
    path = write_hdr(tmp_path / "one.hdr", sky())
    ingest_envmaps([path], split="val", isolate=False)
    assert _rows(db_url)["one"].split == "val"
    ingest_envmaps([path], split="train", isolate=False)  # same content, new split: applied
    row = _rows(db_url)["one"]
    assert row.split == "train" and row.meta["split_source"] == "user"


def test_isolated_validation(db_url: str, tmp_path: Path) -> None:
    write_exr(tmp_path / "a.exr", sky())
    write_hdr(tmp_path / "b.hdr", sky())
    summary = ingest_envmaps([tmp_path], isolate=True)
    assert len(summary.added) == 2


@pytest.mark.realdata
def test_real_envmaps(db_url: str, shared_data: Path) -> None:
    summary = ingest_envmaps([shared_data / "envmaps"], isolate=False)
    assert len(summary.added) == 4 and not summary.rejected
    assert {r.split for r in _rows(db_url).values()} == {"train", "val"}
