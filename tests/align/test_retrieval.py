"""Exact top-k retrieval against brute force (chunk boundaries, ties), the bf16 mode, merge and inversion."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.align.index import ArrayDatabase, Matches, ShardListDatabase, invert, merge_matches
from photoshape_flow.align.retrieval import brute_force, recall_at_k, search


def _int_data(seed: int, shapes: int, views: int, dims: int, queries: int, high: int = 3):
    """Small integers: every float32 distance is exact, and ties are frequent."""
    rng = np.random.default_rng(seed)
    db = rng.integers(0, high, (shapes, views, dims)).astype(np.float16)
    q = rng.integers(0, high, (queries, dims)).astype(np.float32)
    return q, db


@pytest.mark.parametrize(
    ("chunk_rows", "query_batch", "k"),
    [(5, 7, 4), (10, 3, 1), (13, 100, 6), (10_000, 1, 3), (1, 4, 25)],  # 1 shape per chunk .. all at once
)
def test_exact_matches_brute_force_with_ties(chunk_rows: int, query_batch: int, k: int) -> None:
    q, db = _int_data(0, shapes=23, views=5, dims=6, queries=17)
    got = search(q, ArrayDatabase(db), k, chunk_rows=chunk_rows, query_batch=query_batch)
    want = brute_force(q, db, k)
    np.testing.assert_array_equal(got.shapes, want.shapes)
    np.testing.assert_array_equal(got.views, want.views)
    np.testing.assert_array_equal(got.distances, want.distances.astype(np.float32))
    if k > 23:
        assert (got.shapes[:, 23:] == -1).all() and np.isinf(got.distances[:, 23:]).all()
    # there really were ties to break
    assert any(len(set(row)) < len(row) for row in want.distances[:, : min(k, 23)]) or k == 1


def test_at_most_one_view_per_shape_and_best_view() -> None:
    q, db = _int_data(1, shapes=6, views=9, dims=4, queries=5, high=5)
    got = search(q, ArrayDatabase(db), 6, chunk_rows=18)
    for i in range(len(q)):
        assert sorted(got.shapes[i].tolist()) == list(range(6))
        for s, v, d in zip(got.shapes[i], got.views[i], got.distances[i], strict=True):
            per_view = ((db[s].astype(np.float64) - q[i]) ** 2).sum(1)
            assert d == per_view.min() and v == per_view.argmin()


def test_shard_list_database_and_bad_shards() -> None:
    q, db = _int_data(2, shapes=7, views=3, dims=5, queries=4)
    loads: list[int] = []

    def load(i: int) -> np.ndarray:
        loads.append(i)
        return db[i]

    base = ShardListDatabase(list(range(7)), load, num_views=3, dims=5)
    got = search(q, base, 3, chunk_rows=6)
    np.testing.assert_array_equal(got.shapes, brute_force(q, db, 3).shapes)
    assert sorted(loads) == list(range(7))  # every shard read exactly once
    bad = ShardListDatabase([0], lambda _: np.zeros((2, 5)), num_views=3, dims=5)
    with pytest.raises(ValueError, match="expected"):
        search(q, bad, 1)


def test_bf16_mode_recovers_exact_on_clustered_data() -> None:
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 0.4, (40, 1, 64))
    db = (centres + 0.05 * rng.uniform(0, 1, (40, 12, 64))).astype(np.float16)
    q = (db[rng.integers(0, 40, 30), rng.integers(0, 12, 30)].astype(np.float32) + 0.01 * rng.standard_normal((30, 64)))
    exact = search(q, ArrayDatabase(db), 5, chunk_rows=100)
    fast = search(q, ArrayDatabase(db), 5, chunk_rows=100, mode="bf16")
    assert recall_at_k(exact, fast) >= 0.95
    # re-scored distances are float32 values of the chosen views, as in the exact search
    same = (fast.shapes == exact.shapes) & (fast.views == exact.views)
    assert same.mean() > 0.9
    np.testing.assert_allclose(fast.distances[same], exact.distances[same], rtol=1e-5, atol=1e-5)
    for i in range(5):
        for s, v, d in zip(fast.shapes[i], fast.views[i], fast.distances[i], strict=True):
            assert d == pytest.approx(((db[s, v].astype(np.float64) - q[i]) ** 2).sum(), abs=1e-5)
    with pytest.raises(ValueError, match="unknown search mode"):
        search(q, ArrayDatabase(db), 5, mode="fast")


def test_merge_matches_dedupes_and_keeps_nearest() -> None:
    old = Matches(np.array([[10, 11, 12]]), np.array([[0, 1, 2]]), np.array([[1.0, 2.0, 3.0]], np.float32))
    new = Matches(np.array([[11, 20, -1]]), np.array([[5, 6, -1]]), np.array([[2.5, 0.5, np.inf]], np.float32))
    merged = merge_matches(old, new, 3)
    assert merged.shapes.tolist() == [[20, 10, 11]]
    assert merged.views.tolist() == [[6, 0, 5]]  # shape 11 took its new entry
    assert merged.distances.tolist() == [[0.5, 1.0, 2.5]]


def test_invert_top_n_threshold_and_ranks() -> None:
    m = Matches(
        shapes=np.array([[1, 2], [2, 1], [2, 3]]),
        views=np.array([[4, 5], [6, 7], [8, 9]]),
        distances=np.array([[1.0, 2.0], [0.5, 3.0], [0.5, 9.0]], np.float32),
    )
    lists = invert([100, 101, 102], m, top_n=2, max_distance=5.0)
    assert set(lists) == {1, 2}  # shape 3 only had a match beyond the threshold
    assert [(e.exemplar, e.view, e.exemplar_rank) for e in lists[2]] == [(101, 6, 1), (102, 8, 1)]
    assert [(e.exemplar, e.distance) for e in lists[1]] == [(100, 1.0), (101, 3.0)]
