"""A blob store at an fsspec URL (``s3://``, ``gs://``, ``file://``, ``memory://`` ...), read through a local cache.

Workers on several machines share one store this way instead of an NFS mount. The guarantees are
the local folder's:

- *content address*: a blob sits under ``<url>/<aa>/<bb>/<sha256>.<ext>`` (the local layout);
- *nothing half-written is visible under a ref*: object stores (S3, GCS, Azure, memory) get one
  whole-object put, which their semantics make atomic; every other filesystem (``file://``, sftp,
  ...) gets a temporary name in the target's folder and a move, as the local backend does;
- *reads are local files*: `resolve` downloads a blob once into the cache (a `LocalBackend` under
  ``<data_root>/cache/blobs``), checks that its bytes hash to the ref before the cache's atomic
  write, and returns the cached path, so the renderer, OpenCV and numpy read plain files. Blobs
  are immutable, so a cached copy never goes stale; a put also fills the cache (read-your-writes).
"""

from __future__ import annotations

import io
import os
import uuid
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

from photoshape_flow.masking import mask_password
from photoshape_flow.store.local import LocalBackend
from photoshape_flow.store.refs import TEMP_PREFIX, matches_ref, ref_subpath
from photoshape_flow.store.stored import BlobCorruptError, BlobNotFoundError, StoredFile

# Filesystems whose single put is atomic (an object appears whole or not at all) and whose "move" is a
# copy: these get one put. Everything else gets a temporary name and a move (a rename on file://).
SINGLE_PUT_PROTOCOLS = frozenset({"s3", "s3a", "gs", "gcs", "az", "abfs", "abfss", "adl", "oci", "memory"})


class MissingBackendError(RuntimeError):
    """The blob store's URL needs an fsspec backend package that is not installed (one line says which)."""


def missing_backend(url: str) -> str | None:
    """Why `url`'s fsspec backend cannot load (its package named, with the command to install it), or None.

    fsspec itself raises ImportError deep in a call stack; this names the package in one line, before
    anything is opened, for the CLI and the flows alike.
    """
    import importlib.util

    from fsspec.registry import known_implementations, registry

    protocol = url.split("://", 1)[0].lower()
    if protocol in registry:
        return None
    known = known_implementations.get(protocol)
    if known is None:
        return f"blob store {mask_password(url)}: unknown scheme {protocol}:// (no fsspec backend implements it)"
    package = str(known["class"]).split(".", 1)[0]
    if importlib.util.find_spec(package) is not None:
        return None
    return (f"blob store {mask_password(url)}: the {protocol}:// backend needs the {package} package, which is not "
            f"installed (pip install {package})")


class FsspecBackend:
    """Blobs at `url`, cached under `cache_root` on this machine."""

    def __init__(self, url: str, cache_root: str | os.PathLike[str]):
        from fsspec.core import url_to_fs  # imported here: local stores never load fsspec

        self.url = url
        self.shown_url = mask_password(url)
        missing = missing_backend(url)
        if missing is not None:
            raise MissingBackendError(missing)
        self.fs, base = url_to_fs(url)
        self.base = base.rstrip("/")
        protocols = {self.fs.protocol} if isinstance(self.fs.protocol, str) else set(self.fs.protocol)
        self.single_put = bool(protocols & SINGLE_PUT_PROTOCOLS)
        self.cache = LocalBackend(cache_root)

    @property
    def root(self) -> str:
        return self.url

    def remote_path(self, ref: str) -> str:
        return f"{self.base}/{ref_subpath(ref)}"

    def path(self, ref: str) -> Path:
        """The cached copy's path (filled by `resolve`)."""
        return self.cache.path(ref)

    def exists(self, ref: str) -> bool:
        return self.cache.exists(ref) or self.fs.isfile(self.remote_path(ref))

    def resolve(self, ref: str) -> Path:
        """The cached copy, downloaded and verified first when this machine has none."""
        if self.cache.exists(ref):
            return self.cache.path(ref)
        shown = f"{self.shown_url}/{ref_subpath(ref)}"
        try:
            data = self.fs.cat_file(self.remote_path(ref))
        except FileNotFoundError:
            raise BlobNotFoundError(f"{shown}: blob {ref} is missing from the store") from None
        if not matches_ref(data, ref):
            raise BlobCorruptError(f"{shown}: downloaded bytes do not match blob {ref}; not cached")
        self.cache.put(ref, data)
        return self.cache.path(ref)

    def put(self, ref: str, data: bytes) -> None:
        """Upload `data` under `ref` unless a complete copy is there, then cache it."""
        target = self.remote_path(ref)
        if self._size(target) != len(data):
            if self.single_put:
                self.fs.pipe_file(target, data)
            else:
                self._write_and_move(target, data)
        self.cache.put(ref, data)

    def _size(self, path: str) -> int | None:
        try:
            return int(self.fs.info(path)["size"])
        except FileNotFoundError:
            return None

    def _write_and_move(self, target: str, data: bytes) -> None:
        """Write a temporary beside `target`, flush it to disk where possible, and move it into place."""
        folder = target.rsplit("/", 1)[0]
        tmp = f"{folder}/{TEMP_PREFIX}{uuid.uuid4().hex}"
        self.fs.makedirs(folder, exist_ok=True)
        try:
            with self.fs.open(tmp, "wb") as handle:
                handle.write(data)
                handle.flush()
                _fsync(handle)
            self.fs.mv(tmp, target)
        except BaseException:
            self._remove_quietly(tmp)
            raise

    def _remove_quietly(self, path: str) -> None:
        try:
            self.fs.rm_file(path)
        except (FileNotFoundError, OSError):
            pass

    def delete(self, ref: str) -> None:
        self._remove_quietly(self.remote_path(ref))
        self.cache.delete(ref)

    def files(self) -> Iterator[StoredFile]:
        """Every file below the root, from one recursive listing (its sizes and dates come with it)."""
        try:
            listing: dict[str, dict[str, Any]] = self.fs.find(self.base, detail=True)
        except FileNotFoundError:
            return
        for location, info in listing.items():
            stat = (info_mtime(info), int(info.get("size") or 0))
            yield StoredFile(location.rsplit("/", 1)[-1], location, lambda stat=stat: stat)

    def remove(self, location: str) -> None:
        self._remove_quietly(location)


def _fsync(handle: Any) -> None:
    """fsync a local file behind an fsspec handle; other filesystems have nothing to sync."""
    try:
        os.fsync(handle.fileno())
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        pass


def info_mtime(info: dict[str, Any]) -> float | None:
    """A listing entry's modification time as a Unix timestamp; None when the backend gives none.

    Backends name it differently: local ``mtime``, S3 ``LastModified``, GCS ``updated``, memory ``created``.
    """
    for key in ("mtime", "LastModified", "last_modified", "updated", "created"):
        value = info.get(key)
        if value is None:
            continue
        if isinstance(value, datetime):
            return value.timestamp()
        if isinstance(value, int | float):
            return float(value)
        try:
            return datetime.fromisoformat(str(value).replace("Z", "+00:00")).timestamp()
        except ValueError:
            continue
    return None
