"""`BlobStore`: put and read blobs by ref, whichever backend holds them.

The root is a folder (`LocalBackend`, plain `os` calls) or an fsspec URL (`FsspecBackend`, read
through a local cache); callers see the same API either way, and `path`/`resolve` always give a
local file. Rows are committed only after their blobs are written, so a row never points at a
missing or half-written blob. ``gc`` removes blobs no row references, sparing young ones that may
belong to a transaction still in flight.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from photoshape_flow.config import get_settings
from photoshape_flow.store import codecs
from photoshape_flow.store.local import LocalBackend
from photoshape_flow.store.refs import TEMP_PREFIX, check_ref, is_ref, is_url, ref_for
from photoshape_flow.store.remote import FsspecBackend
from photoshape_flow.store.stored import GcReport, StoredFile


class Backend(Protocol):
    """Where blob bytes live; `path`/`resolve` return local files (a remote backend's cached copy)."""

    root: Any

    def path(self, ref: str) -> Path: ...
    def exists(self, ref: str) -> bool: ...
    def resolve(self, ref: str) -> Path: ...
    def put(self, ref: str, data: bytes) -> None: ...
    def delete(self, ref: str) -> None: ...
    def files(self) -> Iterator[StoredFile]: ...
    def remove(self, location: str) -> None: ...


def open_backend(root: str | os.PathLike[str], cache_root: str | os.PathLike[str] | None = None) -> Backend:
    """A `LocalBackend` for a folder, an `FsspecBackend` for a URL (cached under `cache_root`).

    Without `cache_root` a URL store caches under the process settings' ``<data_root>/cache/blobs``,
    so the many ``BlobStore(settings.blob_root)`` call sites need not know about caching.
    """
    if not is_url(root):
        return LocalBackend(root)
    if cache_root is None:
        cache_root = get_settings().blob_cache_root
    return FsspecBackend(str(root), cache_root)


class BlobStore:
    """Immutable, content-named files in a folder or at an fsspec URL."""

    def __init__(self, root: str | os.PathLike[str], cache_root: str | os.PathLike[str] | None = None):
        self._backend = open_backend(root, cache_root)
        self.root = self._backend.root

    @property
    def is_remote(self) -> bool:
        return not isinstance(self._backend, LocalBackend)

    # -- paths -----------------------------------------------------------------------------
    def path(self, ref: str) -> Path:
        """The local file of `ref` (whether or not it exists yet: use `exists`/`resolve` to test or fetch)."""
        return self._backend.path(check_ref(ref))

    def exists(self, ref: str) -> bool:
        return self._backend.exists(check_ref(ref))

    def resolve(self, ref: str) -> Path:
        """Local path of an existing blob (fetched into the cache for a remote store); a clear error when missing."""
        return self._backend.resolve(check_ref(ref))

    # -- writing ---------------------------------------------------------------------------
    def put_bytes(self, data: bytes, ext: str) -> str:
        """Store `data`; returns its ref. Idempotent and atomic."""
        ref = check_ref(ref_for(data, ext))
        self._backend.put(ref, data)
        return ref

    def put_file(self, path: str | os.PathLike[str], ext: str | None = None) -> str:
        """Copy a file into the store (extension from the file name unless given)."""
        source = Path(path)
        return self.put_bytes(source.read_bytes(), ext or source.suffix.lstrip(".") or "bin")

    def put_array(self, array: np.ndarray) -> str:
        """Store a numpy array as .npy (dtype and shape preserved)."""
        return self.put_bytes(codecs.encode_array(array), "npy")

    def put_image(self, image: np.ndarray, ext: str = "png", quality: int = 95) -> str:
        """Store an 8- or 16-bit image (H, W[, C]) as PNG/JPEG/WebP, or a float image as half-float .exr or .hdr."""
        ext = ext.lower().lstrip(".")
        return self.put_bytes(codecs.encode_image(image, ext, quality), ext)

    def put_json(self, payload: Any) -> str:
        return self.put_bytes(codecs.encode_json(payload), "json")

    def delete(self, ref: str) -> None:
        """Remove one blob now (a superseded checkpoint); gc does the rest."""
        self._backend.delete(check_ref(ref))

    # -- reading ---------------------------------------------------------------------------
    def read_bytes(self, ref: str) -> bytes:
        return self.resolve(ref).read_bytes()

    def load_array(self, ref: str) -> np.ndarray:
        return np.load(self.resolve(ref), allow_pickle=False)

    def load_image(self, ref: str, flags: int | None = None) -> np.ndarray:
        """Load an image blob as RGB(A) (uint8/uint16) or float32 for HDR/EXR."""
        return codecs.decode_image(self.resolve(ref), flags)

    def load_json(self, ref: str) -> Any:
        return json.loads(self.read_bytes(ref))

    # -- maintenance -----------------------------------------------------------------------
    def iter_refs(self) -> Iterator[str]:
        for stored in self._backend.files():
            if is_ref(stored.name):
                yield stored.name

    def gc(self, referenced: Iterable[str], grace_seconds: float = 3600.0, dry_run: bool = False) -> GcReport:
        """Remove blobs not in `referenced` and older than `grace_seconds`, and stale temporaries.

        A blob whose age the backend cannot tell is kept (counted young): it may be a write in flight.
        """
        keep = set(referenced)
        now = time.time()
        scanned = removed = young = freed = 0
        for stored in list(self._backend.files()):
            if is_ref(stored.name):
                scanned += 1
                if stored.name in keep:
                    continue
                stat = stored.stat()
                if stat is None:
                    continue
                mtime, size = stat
                if mtime is None or now - mtime < grace_seconds:
                    young += 1
                    continue
                removed += 1
                freed += size
                if not dry_run:
                    self._backend.delete(stored.name)
            elif stored.name.startswith(TEMP_PREFIX) and not dry_run:  # a crashed writer's leftover
                stat = stored.stat()
                if stat is not None and stat[0] is not None and now - stat[0] > grace_seconds:
                    self._backend.remove(stored.location)
        return GcReport(scanned=scanned, removed=removed, kept_young=young, freed_bytes=freed)
