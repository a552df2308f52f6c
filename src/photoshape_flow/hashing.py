"""Stable hashes and seeds derived from content, shared by every layer (standard library only).

Stored rows depend on these values: a ``params_hash`` decides whether a stage redoes an item, and
an item's seed decides its random draws (demo shapes, training renders, baseline picks). Changing
either function's output invalidates stored work, so both are fixed here once.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any


def stable_hash(payload: Any) -> str:
    """sha256 (hex) of `payload` rendered as JSON with sorted keys; non-JSON values by their `str`.

    For JSON-native payloads (dicts, lists, strings, numbers, booleans, None) the result equals the
    hash of ``json.dumps(payload, sort_keys=True)``; `str` only names what JSON cannot (paths, dates).
    """
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def item_seed(*parts: object, sep: str = "/", bits: int = 64) -> int:
    """A seed from an item's natural key: the parts as text joined by `sep`, hashed with sha256.

    The first eight bytes of the digest, little-endian, keep their low `bits` bits. Same key, same
    seed on every run and platform; a new item never shifts the seeds of others. Callers fix `sep`
    and `bits` by convention (their stored data was drawn with them): material assignment uses the
    defaults, training-render specs and demo streams join the global seed and the key with ":".
    """
    if not 1 <= bits <= 64:
        raise ValueError(f"bits must be within 1..64, got {bits}")
    digest = hashlib.sha256(sep.join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(digest[:8], "little") & ((1 << bits) - 1)
