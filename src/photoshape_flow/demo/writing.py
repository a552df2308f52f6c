"""Idempotent file writing: a file whose bytes would not change is left alone (mtime included),
so re-running the demo generator with the same arguments touches nothing downstream watches."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def write_bytes(path: Path, data: bytes) -> bool:
    """Write `data` to `path` atomically unless it already holds exactly these bytes; True if written."""
    path = Path(path)
    if path.is_file() and path.stat().st_size == len(data) and path.read_bytes() == data:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)
    return True


def write_text(path: Path, text: str) -> bool:
    return write_bytes(path, text.encode("utf-8"))


def sha256_hex(data: bytes | str) -> str:
    """The hex sha256 of `data` (text as UTF-8): what the generator stamps its outputs with."""
    return hashlib.sha256(data.encode() if isinstance(data, str) else data).hexdigest()
