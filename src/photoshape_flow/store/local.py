"""A local folder of blobs: the default backend, and the read-through cache of a remote one.

Plain `pathlib`/`os` calls only (no fsspec): the renderer and every stage resolve refs here
thousands of times per batch. Writes go to a temporary file in the target's folder, are fsynced,
then renamed into place, so a ref that exists is always complete.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from photoshape_flow.store.refs import TEMP_PREFIX, ref_subpath
from photoshape_flow.store.stored import BlobNotFoundError, StoredFile


class LocalBackend:
    """Blobs under `root` (a folder on this machine, or one every machine mounts)."""

    def __init__(self, root: str | os.PathLike[str]):
        self.root = Path(root)

    def path(self, ref: str) -> Path:
        return self.root / ref_subpath(ref)

    def exists(self, ref: str) -> bool:
        return self.path(ref).is_file()

    def resolve(self, ref: str) -> Path:
        path = self.path(ref)
        if not path.is_file():
            raise BlobNotFoundError(f"{path}: blob {ref} is missing from the store")
        return path

    def put(self, ref: str, data: bytes) -> None:
        """Write `data` under `ref` unless a complete copy is there (temp file + fsync + rename)."""
        target = self.path(ref)
        if target.is_file() and target.stat().st_size == len(data):
            return
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX, dir=target.parent)
        try:
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def delete(self, ref: str) -> None:
        self.path(ref).unlink(missing_ok=True)

    def files(self) -> Iterator[StoredFile]:
        """Every file in the layout (refs and writers' temporaries), stat deferred until asked."""
        if not self.root.is_dir():
            return
        for path in self.root.glob("??/??/*"):
            yield StoredFile(path.name, str(path), lambda path=path: _stat(path))

    def remove(self, location: str) -> None:
        Path(location).unlink(missing_ok=True)


def _stat(path: Path) -> tuple[float | None, int] | None:
    try:
        stat = path.stat()
    except FileNotFoundError:  # removed since the listing (another gc, a superseded checkpoint)
        return None
    return stat.st_mtime, stat.st_size
