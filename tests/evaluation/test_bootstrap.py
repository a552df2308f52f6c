"""Bootstrap intervals over exemplars: the mean, the interval's width and the paired difference."""

from __future__ import annotations

import numpy as np

from photoshape_flow.evaluation.bootstrap import difference_interval, mean_interval


def test_mean_is_pooled_and_interval_brackets_it():
    obs = {1: [1.0, 1.0, 0.0], 2: [0.0], 3: [1.0, 0.0], 4: [1.0]}
    est = mean_interval(obs)
    assert est.value == 4 / 7 and est.count == 7 and est.exemplars == 4
    assert est.low < est.value < est.high


def test_interval_shrinks_with_more_exemplars_and_is_deterministic():
    rng = np.random.default_rng(3)
    few = {i: list(rng.random(3) < 0.6) for i in range(10)}
    many = {i: list(rng.random(3) < 0.6) for i in range(400)}
    a, b = mean_interval(few), mean_interval(many)
    assert (b.high - b.low) < 0.5 * (a.high - a.low)
    assert mean_interval(few) == a
    # the true rate lies inside the large sample's interval
    assert b.low < 0.6 < b.high


def test_parts_of_one_exemplar_are_not_independent():
    # 20 exemplars whose 10 parts are all right or all wrong: the interval must be as wide as 20
    # independent coin flips, not 200
    clustered = {i: [float(i % 2)] * 10 for i in range(20)}
    independent = {i: [float(j % 2) for j in range(10)] for i in range(20)}
    wide, narrow = mean_interval(clustered), mean_interval(independent)
    assert wide.value == narrow.value == 0.5
    assert wide.high - wide.low > 0.3
    assert narrow.high - narrow.low < 0.01


def test_paired_difference_sees_a_consistent_gain_that_unpaired_intervals_overlap():
    rng = np.random.default_rng(0)
    base = {i: list(rng.random(4) < rng.uniform(0.1, 0.9)) for i in range(40)}
    better = {i: [1.0 if not v and j == 0 else float(v) for j, v in enumerate(vals)] for i, vals in base.items()}
    diff = difference_interval(better, base)
    assert diff.value > 0 and diff.low > 0  # a gain on every exemplar where possible: significant
    a, b = mean_interval(better), mean_interval(base)
    assert a.low < b.high  # the two separate intervals overlap nonetheless


def test_difference_only_over_exemplars_both_observed_and_empty_cases():
    assert difference_interval({1: [1.0], 2: [1.0]}, {2: [0.0], 3: [0.0]}).value == 1.0
    assert difference_interval({1: [1.0]}, {2: [0.0]}).value is None
    assert mean_interval({}).value is None
    single = mean_interval({7: [0.25, 0.75]})
    assert single.value == 0.5 and single.low is None
    assert mean_interval({1: [float("nan")], 2: [1.0]}).value == 1.0
