"""Blob names: a ref is the sha256 of a blob's bytes plus an extension (``<sha256>.<ext>``).

Every backend lays blobs out the same way, ``<root>/<aa>/<bb>/<ref>``, so a local folder, a
local cache of a remote store and the remote store itself are interchangeable copies.
"""

from __future__ import annotations

import hashlib
import os
import re

REF_PATTERN = re.compile(r"^[0-9a-f]{64}\.[a-z0-9]{1,8}$")
TEMP_PREFIX = ".tmp-"  # writers' temporary files; never a ref, swept by gc once stale


def is_ref(value: object) -> bool:
    """True when `value` looks like a blob ref."""
    return isinstance(value, str) and REF_PATTERN.match(value) is not None


def check_ref(ref: str) -> str:
    """`ref` itself, or a ValueError: a ref becomes a path, so nothing else may pass (``../..``)."""
    if not is_ref(ref):
        raise ValueError(f"not a blob ref: {ref!r}")
    return ref


def ref_subpath(ref: str) -> str:
    """``aa/bb/<ref>``: where `ref` sits below a store's root (two levels keep folders small)."""
    return f"{ref[:2]}/{ref[2:4]}/{ref}"


def ref_for(data: bytes, ext: str) -> str:
    """The ref of `data` stored with extension `ext`."""
    return f"{sha256_bytes(data)}.{ext.lower().lstrip('.')}"


def matches_ref(data: bytes, ref: str) -> bool:
    """True when `data` hashes to the digest `ref` names (a download is checked with this)."""
    return sha256_bytes(data) == ref.split(".", 1)[0]


def is_url(root: str | os.PathLike[str]) -> bool:
    """True when a configured store root is an fsspec URL (``s3://``, ``file://`` ...), not a folder."""
    return isinstance(root, str) and "://" in root


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Streaming sha256 of a file (used for provenance of ingested sources)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()
