"""What every backend shares with `BlobStore`: its errors and its listing entries."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


class BlobNotFoundError(FileNotFoundError):
    """A ref names a blob that is not in the store."""


class BlobCorruptError(ValueError):
    """A blob's bytes do not hash to its ref (a damaged or tampered copy); it is never cached."""


@dataclass(frozen=True)
class StoredFile:
    """One file of a store's layout: `name` (a ref or a temporary), where it is, and a lazy stat.

    `stat()` returns ``(mtime or None when the backend cannot tell, size)``, or None when the file
    has gone since the listing; it is lazy because gc needs it only for unreferenced blobs.
    """

    name: str
    location: str
    stat: Callable[[], tuple[float | None, int] | None]


@dataclass(frozen=True)
class GcReport:
    scanned: int
    removed: int
    kept_young: int
    freed_bytes: int
