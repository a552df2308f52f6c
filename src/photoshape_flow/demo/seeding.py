"""Stable per-item random streams: the same (seed, keys) gives the same numbers on every run and
platform, and adding items never shifts the streams of others (unlike drawing from one generator)."""

from __future__ import annotations

import numpy as np

from photoshape_flow.hashing import item_seed


def child_rng(seed: int, *keys: object) -> np.random.Generator:
    """The generator of the stream named by `keys` under the demo's `seed`."""
    return np.random.default_rng(item_seed(int(seed), *keys, sep=":"))
