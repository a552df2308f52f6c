"""One blob-store contract over every backend: a local folder, file:// and memory:// (fsspec).

The remote kinds are read through a local cache, so a second store on the same URL with its own
cache plays "another machine": it must see what the first wrote, fetch it once, and reject bytes
that do not hash to their ref.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import fsspec
import numpy as np
import pytest

from photoshape_flow.store import BlobCorruptError, BlobNotFoundError, BlobStore, is_ref, sha256_bytes

KINDS = ("local", "file", "memory")
REMOTE = ("file", "memory")
MakeStore = Callable[..., BlobStore]


@pytest.fixture
def root(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The store root of one kind; a memory:// root is unique to the test and emptied afterwards."""
    kind = request.param
    if kind == "local":
        yield str(tmp_path / "blobs")
    elif kind == "file":
        yield (tmp_path / "shared").as_uri()
    else:
        url = f"memory://test-{uuid.uuid4().hex}/blobs"
        yield url
        fs, path = fsspec.core.url_to_fs(url)
        if fs.exists(path):
            fs.rm(path, recursive=True)


@pytest.fixture
def make_store(root: str, tmp_path: Path) -> MakeStore:
    """`make_store(machine)`: a store on `root` with that machine's own cache folder."""
    return lambda machine="a": BlobStore(root, cache_root=tmp_path / f"cache-{machine}")


def _remote(store: BlobStore, ref: str) -> tuple[fsspec.AbstractFileSystem, str]:
    backend = store._backend  # the remote copy itself, to damage or inspect it
    return backend.fs, backend.remote_path(ref)


@pytest.mark.parametrize("root", KINDS, indirect=True)
def test_contract_round_trip(make_store: MakeStore) -> None:
    store = make_store()
    ref = store.put_bytes(b"hello", "TXT")
    assert ref == f"{sha256_bytes(b'hello')}.txt" and is_ref(ref)
    assert store.put_bytes(b"hello", "txt") == ref  # idempotent: same bytes, same ref
    path = store.resolve(ref)
    assert isinstance(path, Path) and path.read_bytes() == b"hello" and store.read_bytes(ref) == b"hello"
    arr = np.arange(12, dtype=np.float16).reshape(3, 4)
    array_ref = store.put_array(arr)
    assert np.array_equal(store.load_array(array_ref), arr)
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0] = 200
    ids = np.array([[0, 1], [300, 65535]], np.uint16)
    hdr = np.random.default_rng(0).random((4, 4, 3)).astype(np.float32) * 10
    image_refs = [store.put_image(rgb), store.put_image(ids), store.put_image(hdr, "exr")]
    assert np.array_equal(store.load_image(image_refs[0]), rgb)
    assert np.array_equal(store.load_image(image_refs[1]), ids)
    assert np.allclose(store.load_image(image_refs[2]), hdr, rtol=1e-3)
    doc = store.put_json({"b": 1, "a": [1, 2]})
    assert store.load_json(doc) == {"a": [1, 2], "b": 1} and doc == store.put_json({"a": [1, 2], "b": 1})
    assert sorted(store.iter_refs()) == sorted({ref, array_ref, doc, *image_refs})

    other = make_store("b")  # another machine: its own (empty) cache, the same store
    assert other.exists(ref)
    if store.is_remote:
        assert not other.path(ref).is_file()  # not fetched until resolved
    assert other.resolve(ref).read_bytes() == b"hello" and other.path(ref).is_file()
    missing = "0" * 64 + ".png"
    assert not other.exists(missing)
    with pytest.raises(BlobNotFoundError, match=missing):
        other.resolve(missing)
    with pytest.raises(ValueError):
        other.path("../../etc/passwd")


@pytest.mark.parametrize("root", KINDS, indirect=True)
def test_gc_removes_only_old_unreferenced_blobs(make_store: MakeStore) -> None:
    store = make_store()
    keep, old = store.put_bytes(b"keep", "bin"), store.put_bytes(b"old", "bin")
    report = store.gc([keep], grace_seconds=3600)
    assert (report.scanned, report.removed, report.kept_young) == (2, 0, 1)
    report = store.gc([keep], grace_seconds=-1)  # every blob is "old" now
    assert (report.scanned, report.removed, report.freed_bytes) == (2, 1, 3)
    assert store.exists(keep) and not store.exists(old) and list(store.iter_refs()) == [keep]
    assert not store.path(old).exists()  # a remote store's cached copy goes too


@pytest.mark.parametrize("root", ("local", "file"), indirect=True)
def test_gc_sweeps_a_crashed_writers_temporary(make_store: MakeStore) -> None:
    store = make_store()
    ref = store.put_bytes(b"kept", "bin")
    base = Path(store.root if not store.is_remote else store._backend.base)
    leftover = base / ref[:2] / ref[2:4] / ".tmp-crashed"
    leftover.write_bytes(b"half")
    assert list(store.iter_refs()) == [ref]  # never mistaken for a blob
    store.gc([ref], grace_seconds=3600)
    assert leftover.exists()  # young: may be a write in flight
    store.gc([ref], grace_seconds=-1)
    assert not leftover.exists() and store.exists(ref)


def _fail_mid_write(kind: str, store: BlobStore, monkeypatch: pytest.MonkeyPatch) -> None:
    """Make the next write die part-way, the way each backend can: after the temporary file's bytes
    (local: before the rename; file://: half the bytes, then an error), or as a failed whole-object put."""
    if kind == "local":
        monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError("disk full")))
        return
    fs = store._backend.fs
    if kind == "file":
        real_open = fs.open

        def torn_open(path: str, mode: str = "rb", **kwargs: object):  # type: ignore[no-untyped-def]
            handle = real_open(path, mode, **kwargs)
            if "w" in mode:
                real_write = handle.write

                def write(data: bytes) -> int:
                    real_write(data[: len(data) // 2])
                    raise OSError("connection lost")

                handle.write = write
            return handle

        monkeypatch.setattr(fs, "open", torn_open)
    else:
        monkeypatch.setattr(fs, "pipe_file", lambda *a, **k: (_ for _ in ()).throw(OSError("connection lost")))


@pytest.mark.parametrize("root", KINDS, indirect=True)
def test_interrupted_write_leaves_no_visible_ref(request: pytest.FixtureRequest, make_store: MakeStore,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    kind = request.node.callspec.params["root"]
    store = make_store()
    data = b"x" * 4096
    with monkeypatch.context() as patch:
        _fail_mid_write(kind, store, patch)
        with pytest.raises(OSError):
            store.put_bytes(data, "bin")
    ref = f"{sha256_bytes(data)}.bin"
    assert list(store.iter_refs()) == [] and not store.exists(ref) and not make_store("b").exists(ref)
    assert not store.path(ref).exists()
    if kind != "memory":  # the temporary is gone too (gc sweeps a crashed process's later)
        base = Path(store.root if kind == "local" else store._backend.base)
        assert not list(base.rglob(".tmp-*"))
    assert store.put_bytes(data, "bin") == ref and make_store("b").read_bytes(ref) == data  # a retry succeeds


@pytest.mark.parametrize("root", REMOTE, indirect=True)
def test_corrupted_download_is_rejected(make_store: MakeStore) -> None:
    ref = make_store().put_bytes(b"genuine bytes", "bin")
    fs, remote = _remote(make_store(), ref)
    fs.pipe_file(remote, b"tampered bytes")  # same ref, other content: a damaged copy
    other = make_store("b")
    with pytest.raises(BlobCorruptError, match=ref):
        other.resolve(ref)
    assert not other.path(ref).exists()  # nothing damaged entered the cache
    assert make_store().read_bytes(ref) == b"genuine bytes"  # the writer's verified cached copy is intact


def test_a_url_whose_backend_is_not_installed_is_one_line(settings_env: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """`s3://` without s3fs: one line naming the package, exit 1, no ImportError traceback."""
    import importlib.util

    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.config import get_settings
    from photoshape_flow.store.remote import FsspecBackend, MissingBackendError, missing_backend

    if importlib.util.find_spec("s3fs") is not None:
        pytest.skip("s3fs is installed here")
    monkeypatch.setenv("PHOTOSHAPE_BLOB_ROOT", "s3://user:se@cret@bucket/blobs")
    get_settings.cache_clear()
    result = CliRunner().invoke(app, ["ingest", "materials", str(settings_env)])
    flat = " ".join(result.output.split())
    assert result.exit_code == 1 and "Traceback" not in flat and "se@cret" not in flat, result.output
    assert "s3:// backend needs the s3fs package, which is not installed (pip install s3fs)" in flat, flat
    assert missing_backend("memory://x") is None
    with pytest.raises(MissingBackendError, match="pip install s3fs"):
        FsspecBackend("s3://bucket/blobs", settings_env / "cache")
