"""The content-addressed blob store: names from content, atomic writes, dedupe, gc."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.store import BlobNotFoundError, BlobStore, is_ref, sha256_bytes


def test_put_bytes_is_content_addressed_and_deduplicated(tmp_path: Path) -> None:
    store = BlobStore(tmp_path)
    ref = store.put_bytes(b"hello", "txt")
    assert ref == f"{sha256_bytes(b'hello')}.txt" and is_ref(ref)
    assert store.put_bytes(b"hello", "txt") == ref
    assert store.read_bytes(ref) == b"hello"
    assert len(list(store.iter_refs())) == 1
    assert not list(tmp_path.rglob(".tmp-*"))


def test_failed_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = BlobStore(tmp_path)

    def broken_replace(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError):
        store.put_bytes(b"data", "bin")
    assert list(store.iter_refs()) == []
    assert not list(tmp_path.rglob(".tmp-*"))


def test_arrays_and_images_round_trip(tmp_path: Path) -> None:
    store = BlobStore(tmp_path)
    arr = np.arange(12, dtype=np.float16).reshape(3, 4)
    assert np.array_equal(store.load_array(store.put_array(arr)), arr)
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0] = 200  # red stays red through the BGR-based encoder
    assert np.array_equal(store.load_image(store.put_image(rgb)), rgb)
    ids = np.array([[0, 1], [300, 65535]], np.uint16)
    assert np.array_equal(store.load_image(store.put_image(ids)), ids)
    hdr = np.random.default_rng(0).random((4, 4, 3)).astype(np.float32) * 10
    assert np.allclose(store.load_image(store.put_image(hdr, "exr")), hdr, rtol=1e-3)


def test_missing_blob_error_names_the_file(tmp_path: Path) -> None:
    store = BlobStore(tmp_path)
    ref = "0" * 64 + ".png"
    with pytest.raises(BlobNotFoundError, match=ref):
        store.resolve(ref)
    with pytest.raises(ValueError):
        store.path("../../etc/passwd")


def test_gc_removes_only_old_unreferenced_blobs(tmp_path: Path) -> None:
    store = BlobStore(tmp_path)
    keep = store.put_bytes(b"keep", "bin")
    old = store.put_bytes(b"old", "bin")
    young = store.put_bytes(b"young", "bin")
    past = time.time() - 7200
    os.utime(store.path(old), (past, past))
    os.utime(store.path(keep), (past, past))
    report = store.gc([keep], grace_seconds=3600)
    assert (report.scanned, report.removed, report.kept_young) == (3, 1, 1)
    assert store.exists(keep) and store.exists(young) and not store.exists(old)
