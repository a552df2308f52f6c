"""Safe reading of zip archives (Sweet Home 3D catalogs): no path traversal, no bombs, no links.

Members are addressed by normalised POSIX names inside the archive. A member name that is absolute,
has a drive letter, climbs out with `..`, is a symbolic link, or decompresses beyond the limits
raises `UnsafeArchiveError` naming the member, so one bad item never escapes its temporary folder.
"""

from __future__ import annotations

import posixpath
import re
import stat
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

from photoshape_flow.geometry.raw import BadShapeError

_CHUNK = 1 << 20


class UnsafeArchiveError(BadShapeError):
    """An archive member is unsafe to extract (traversal, link, bomb, over a size limit)."""


@dataclass(frozen=True)
class ArchiveLimits:
    max_members: int = 200_000
    max_member_bytes: int = 512 * 1024 * 1024
    max_ratio: float = 200.0  # uncompressed / compressed, for members over 1 MiB


def normalise_member(name: str) -> str:
    """A member name as a clean relative POSIX path, or UnsafeArchiveError."""
    cleaned = name.replace("\\", "/")
    if cleaned.startswith("/") or re.match(r"^[A-Za-z]:", cleaned) or "\x00" in cleaned:
        raise UnsafeArchiveError(f"unsafe archive member {name!r} (absolute path)")
    norm = posixpath.normpath(cleaned)
    if norm == ".." or norm.startswith("../") or norm.startswith("/"):
        raise UnsafeArchiveError(f"unsafe archive member {name!r} (path traversal)")
    return norm


def join_member(base_dir: str, relative: str) -> str:
    """`relative` (as written in an OBJ/MTL inside the archive) resolved against `base_dir`."""
    relative = relative.replace("\\", "/").strip()
    if relative.startswith("/") or re.match(r"^[A-Za-z]:", relative):
        raise UnsafeArchiveError(f"unsafe reference {relative!r} (absolute path)")
    joined = posixpath.normpath(posixpath.join(base_dir, relative)) if base_dir else posixpath.normpath(relative)
    if joined == ".." or joined.startswith("../"):
        raise UnsafeArchiveError(f"unsafe reference {relative!r} (path traversal)")
    return joined


class SafeZip:
    """A read-only view of a zip file with validated member access."""

    def __init__(self, path: Path, limits: ArchiveLimits | None = None):
        self.path = Path(path)
        self.limits = limits or ArchiveLimits()
        try:
            self._zip = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError, ValueError) as exc:
            raise BadShapeError(f"{self.path.name}: not a readable zip archive ({exc})") from exc
        infos = self._zip.infolist()
        if len(infos) > self.limits.max_members:
            raise UnsafeArchiveError(f"{self.path.name}: {len(infos)} members (limit {self.limits.max_members})")
        self._by_lower: dict[str, zipfile.ZipInfo] = {}
        self._unsafe: dict[str, str] = {}
        for info in infos:
            if info.is_dir():
                continue
            try:
                norm = normalise_member(info.filename)
            except UnsafeArchiveError as exc:
                self._unsafe[info.filename.replace("\\", "/").lower()] = str(exc)
                continue
            self._by_lower.setdefault(norm.lower(), info)

    def close(self) -> None:
        self._zip.close()

    def __enter__(self) -> SafeZip:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def names(self) -> list[str]:
        return [normalise_member(i.filename) for i in self._by_lower.values()]

    def find(self, name: str) -> zipfile.ZipInfo | None:
        """The member called `name` (case-insensitive), None if absent; raises if it is unsafe."""
        key = name.replace("\\", "/").lower()
        if key in self._unsafe:
            raise UnsafeArchiveError(self._unsafe[key])
        return self._by_lower.get(posixpath.normpath(key))

    def read(self, name: str) -> bytes:
        """Bytes of a member, enforcing link, size and compression-ratio limits while inflating."""
        info = self.find(name)
        if info is None:
            raise KeyError(name)
        mode = (info.external_attr >> 16) & 0o170000
        if mode == stat.S_IFLNK:
            raise UnsafeArchiveError(f"unsafe archive member {info.filename!r} (symbolic link)")
        limit = self.limits.max_member_bytes
        if info.file_size > limit:
            raise UnsafeArchiveError(f"archive member {info.filename!r} is {info.file_size} bytes (limit {limit})")
        if info.file_size > _CHUNK and info.file_size / max(info.compress_size, 1) > self.limits.max_ratio:
            raise UnsafeArchiveError(
                f"archive member {info.filename!r} looks like a decompression bomb "
                f"({info.compress_size} -> {info.file_size} bytes)"
            )
        chunks: list[bytes] = []
        total = 0
        try:
            with self._zip.open(info) as handle:
                while block := handle.read(_CHUNK):
                    total += len(block)
                    if total > min(limit, info.file_size + _CHUNK):
                        raise UnsafeArchiveError(
                            f"archive member {info.filename!r} inflates beyond its declared size"
                        )
                    chunks.append(block)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, NotImplementedError) as exc:
            raise BadShapeError(f"archive member {info.filename!r} is corrupt ({exc})") from exc
        return b"".join(chunks)

    def extract(self, name: str, dest_root: Path, data: bytes | None = None) -> Path:
        """Write a member (or its already-read `data`) under `dest_root`; returns the file path."""
        if data is None:
            data = self.read(name)
        info = self.find(name)
        assert info is not None
        target = (dest_root / normalise_member(info.filename)).resolve()
        if not target.is_relative_to(dest_root.resolve()):
            raise UnsafeArchiveError(f"unsafe archive member {info.filename!r} (path traversal)")
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
        return target
