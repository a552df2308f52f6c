"""`hashing`: the hash and seed conventions that stored rows depend on, pinned to their formulas."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from photoshape_flow.hashing import item_seed, stable_hash


def test_stable_hash_is_sorted_json_sha256_and_names_non_json_values_by_str() -> None:
    payload = {"b": [1, 2.5, None, True], "a": {"y": "x", "x": (1, 2)}}
    expected = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()
    assert stable_hash(payload) == expected  # JSON-native: the same with or without default=str
    assert stable_hash({"path": Path("/a/b")}) == stable_hash({"path": "/a/b"})


def test_item_seed_conventions() -> None:
    def digest_int(text: str) -> int:
        return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")

    # material assignment: parts joined by "/", 64 bits
    assert item_seed(12, 3, "no-classifier") == digest_int("12/3/no-classifier")
    # training-render specs: "<global seed>:<key>", 63 bits
    key = "bootstrap/train/000007"
    assert item_seed(5, key, sep=":", bits=63) == digest_int(f"5:{key}") & ((1 << 63) - 1)
    # demo streams: "<seed>:<key>:<key>...", 64 bits
    assert item_seed(0, "shape", 3, sep=":") == digest_int("0:shape:3")
    with pytest.raises(ValueError):
        item_seed("x", bits=65)
