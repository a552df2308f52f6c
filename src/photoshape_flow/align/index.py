"""What the search of section 4.1 reads and writes: the descriptor database, the match lists and
the reverse index.

The database is the descriptors of every view of every shape, one (views x dims) shard per shape,
read in chunks of whole shards (`ShardDatabase`: in memory, or loaded on demand from the blob store).
A search (`align.retrieval.search`) yields per-exemplar `Matches`; `merge_matches` folds in the
matches of shapes that joined later, and `invert` turns them into per-shape lists of exemplars (the
paper keeps the top 12 per shape and drops pairs whose distance is too large).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


class ShardDatabase(Protocol):
    """A sequence of per-shape descriptor shards, all (num_views, dims)."""

    num_shapes: int
    num_views: int
    dims: int

    def load(self, start: int, stop: int) -> np.ndarray:
        """Shards start..stop-1 as one (stop - start, num_views, dims) array (float16 or float32)."""
        ...


@dataclass
class ArrayDatabase:
    """An in-memory (shapes, views, dims) array."""

    array: np.ndarray

    @property
    def num_shapes(self) -> int:
        return int(self.array.shape[0])

    @property
    def num_views(self) -> int:
        return int(self.array.shape[1])

    @property
    def dims(self) -> int:
        return int(self.array.shape[2])

    def load(self, start: int, stop: int) -> np.ndarray:
        return self.array[start:stop]


@dataclass
class ShardListDatabase:
    """Shards loaded on demand: `load_one(item)` returns one (num_views, dims) array."""

    items: Sequence[Any]
    load_one: Callable[[Any], np.ndarray]
    num_views: int
    dims: int

    @property
    def num_shapes(self) -> int:
        return len(self.items)

    def load(self, start: int, stop: int) -> np.ndarray:
        shards = [np.asarray(self.load_one(item)) for item in self.items[start:stop]]
        for item, shard in zip(self.items[start:stop], shards, strict=True):
            if shard.shape != (self.num_views, self.dims):
                raise ValueError(f"shard {item!r} has shape {shard.shape}, expected {(self.num_views, self.dims)}")
        return np.stack(shards)


@dataclass
class Matches:
    """Per query: the top-k database positions (shapes), their best views and squared distances.

    Rows are sorted by distance; where fewer than k shapes exist, shapes/views are -1 and
    distances +inf.
    """

    shapes: np.ndarray  # (Q, k) int64
    views: np.ndarray  # (Q, k) int64
    distances: np.ndarray  # (Q, k) float32

    @classmethod
    def empty(cls, num_queries: int, k: int) -> Matches:
        return cls(
            np.full((num_queries, k), -1, np.int64),
            np.full((num_queries, k), -1, np.int64),
            np.full((num_queries, k), np.inf, np.float32),
        )

    def take(self, rows: np.ndarray | Sequence[int]) -> Matches:
        idx = np.asarray(rows, np.int64)
        return Matches(self.shapes[idx], self.views[idx], self.distances[idx])


def merge_matches(old: Matches, new: Matches, k: int) -> Matches:
    """Per-row union of two match lists over *shape keys*, one entry per shape (the `new` entry wins),
    the k nearest kept (ties: `old` first, then by order). Used when new shapes join the database.
    """
    if old.shapes.shape[0] != new.shapes.shape[0]:
        raise ValueError("merge_matches: different numbers of queries")
    out = Matches.empty(old.shapes.shape[0], k)
    for i in range(old.shapes.shape[0]):
        fresh = {int(s) for s in new.shapes[i] if s >= 0}
        entries = [
            (float(d), 0, j, int(s), int(v))
            for j, (s, v, d) in enumerate(zip(old.shapes[i], old.views[i], old.distances[i], strict=True))
            if s >= 0 and int(s) not in fresh
        ]
        entries += [
            (float(d), 1, j, int(s), int(v))
            for j, (s, v, d) in enumerate(zip(new.shapes[i], new.views[i], new.distances[i], strict=True))
            if s >= 0
        ]
        entries.sort()
        for j, (d, _, _, s, v) in enumerate(entries[:k]):
            out.shapes[i, j], out.views[i, j], out.distances[i, j] = s, v, d
    return out


@dataclass(frozen=True)
class ReverseEntry:
    """One exemplar in a shape's list: the best view, the distance, the shape's rank for the exemplar."""

    exemplar: int
    view: int
    distance: float
    exemplar_rank: int


def invert(
    exemplars: Sequence[int],
    matches: Matches,
    top_n: int = 12,
    max_distance: float | None = None,
) -> dict[int, list[ReverseEntry]]:
    """Per-shape lists from per-exemplar matches (whose `shapes` hold shape keys).

    Each shape keeps its `top_n` nearest exemplars (ties: lower exemplar key first) among those
    whose distance is at most `max_distance` (None keeps all).
    """
    lists: dict[int, list[ReverseEntry]] = {}
    for i, exemplar in enumerate(exemplars):
        for rank, (s, v, d) in enumerate(
            zip(matches.shapes[i], matches.views[i], matches.distances[i], strict=True), start=1
        ):
            if s < 0 or not np.isfinite(d) or (max_distance is not None and d > max_distance):
                continue
            lists.setdefault(int(s), []).append(ReverseEntry(int(exemplar), int(v), float(d), rank))
    for shape, entries in lists.items():
        entries.sort(key=lambda e: (e.distance, e.exemplar))
        lists[shape] = entries[:top_n]
    return lists
