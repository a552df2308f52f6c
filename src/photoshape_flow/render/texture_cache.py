"""A least-recently-used cache of decoded textures, bounded by their bytes rather than their count.

Why: decoded textures are float32 (a 1024^2 RGB map is 12 MiB, a 256^2 one 0.75 MiB) and the fit
re-renders every candidate material of every part, so the cache must hold a whole collection's
maps at once or it thrashes: a 24-entry cache held six of a 15-material collection's four maps
each and decoded 3,192 textures in one fit calibration (42 s of its 271 s). A count bound that
fits the demo would grow without limit on a collection of 2K scans; a byte bound does not.
Thread-safe: Prefect may run tasks that render in threads of one process.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable

import numpy as np

TEXTURE_CACHE_BYTES = 1 << 30  # decoded textures kept per process (1 GiB: the 2-core machine has 24)


class ByteLRU:
    """Arrays by key, the least recently used dropped first once their bytes pass `max_bytes`.

    An array larger than the whole budget is returned but not kept. Cached arrays are shared:
    callers must not write to them.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self.bytes = 0
        self._items: OrderedDict[Hashable, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._items)

    def get_or_load(self, key: Hashable, load: Callable[[], np.ndarray]) -> np.ndarray:
        """The array cached under `key`, or `load()`'s (then cached), marked most recently used."""
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                self.hits += 1
                return self._items[key]
            self.misses += 1
        value = load()  # outside the lock: decoding takes milliseconds; a second loader's copy is equal
        with self._lock:
            if key not in self._items and value.nbytes <= self.max_bytes:
                self._items[key] = value
                self.bytes += value.nbytes
                while self.bytes > self.max_bytes:
                    _, dropped = self._items.popitem(last=False)
                    self.bytes -= dropped.nbytes
        return value

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self.bytes = 0
