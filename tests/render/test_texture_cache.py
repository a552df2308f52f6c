"""The decoded-texture cache (`render.texture_cache.ByteLRU`): bounded by bytes, least recently used out first."""

from __future__ import annotations

import numpy as np

from photoshape_flow.render.texture_cache import ByteLRU


def _array(kib: int) -> np.ndarray:
    return np.zeros(kib * 256, np.float32)  # kib KiB


def test_the_least_recently_used_array_goes_first_once_the_bytes_pass_the_budget() -> None:
    cache = ByteLRU(10 * 1024)
    loads: list[str] = []

    def get(key: str, kib: int) -> np.ndarray:
        return cache.get_or_load(key, lambda: loads.append(key) or _array(kib))

    get("a", 4), get("b", 4)
    get("a", 4)  # a is now the most recent
    get("c", 4)  # 12 KiB > 10: b goes, not a
    assert loads == ["a", "b", "c"] and cache.bytes == 8 * 1024 and len(cache) == 2
    get("a", 4)
    get("b", 4)
    assert loads == ["a", "b", "c", "b"] and (cache.hits, cache.misses) == (2, 4)


def test_an_array_larger_than_the_budget_is_returned_not_kept() -> None:
    cache = ByteLRU(2 * 1024)
    value = cache.get_or_load("big", lambda: _array(4))
    assert value.nbytes == 4 * 1024 and len(cache) == 0 and cache.bytes == 0
    cache.get_or_load("small", lambda: _array(1))
    cache.clear()
    assert len(cache) == 0 and cache.bytes == 0
