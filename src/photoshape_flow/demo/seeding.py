"""Stable per-item random streams: the same (seed, keys) gives the same numbers on every run and
platform, and adding items never shifts the streams of others (unlike drawing from one generator)."""

from __future__ import annotations

import hashlib

import numpy as np


def child_seed(seed: int, *keys: object) -> int:
    text = ":".join([str(int(seed)), *(str(k) for k in keys)])
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")


def child_rng(seed: int, *keys: object) -> np.random.Generator:
    return np.random.default_rng(child_seed(seed, *keys))
