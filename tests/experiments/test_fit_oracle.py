"""The oracle's partial degradation (`deg:<parts>`) splits the exemplar degradation without changing it."""

from __future__ import annotations

import numpy as np
import pytest
from experiments.fit_oracle.run import DEGRADATION_PARTS, clean_photo, partly_degraded

from photoshape_flow.networks.validation_photos import as_photo


def _render() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    hdr = rng.uniform(0.0, 1.2, (40, 40, 3)).astype(np.float32)
    ids = np.ones((40, 40), np.int32)
    ids[:6] = 0
    return hdr, ids


def test_all_parts_are_the_whole_degradation_and_none_is_the_clean_photo() -> None:
    hdr, ids = _render()
    assert np.array_equal(partly_degraded(hdr, ids, 11, set(DEGRADATION_PARTS)), as_photo(hdr, ids, 11))
    assert np.array_equal(partly_degraded(hdr, ids, 11, set()), clean_photo(hdr, ids))


def test_one_part_changes_the_photo_and_an_unknown_part_is_refused() -> None:
    hdr, ids = _render()
    clean = clean_photo(hdr, ids).astype(int)
    balanced = partly_degraded(hdr, ids, 11, {"wb"}).astype(int)
    assert np.abs(balanced - clean).max() > 0
    with pytest.raises(SystemExit, match="unknown part 'gamma'"):
        partly_degraded(hdr, ids, 11, {"gamma"})


def test_misses_are_counted_by_kind_and_the_split_prior_keeps_the_hand_set_costs() -> None:
    """Two dumped cases: one right, one lost to a proposed material of another substance over a truth
    at the prior floor that is closer in colour. The split cost starts from the hand-set costs exactly."""
    from experiments.fit_oracle.misses import SPLIT_TERMS, breakdown, cases_of, hand_set, models

    floor = float(-np.log(0.02))
    right = {"group": "a", "truth": 0, "substances": ["wood", "fabric"],
             "features": [[0.1, 0.1, 0.1, 0.0, 0.1, 0.5], [0.9, 0.2, 0.2, 0.0, 0.3, 1.0]]}
    lost = {"group": "b", "truth": 1, "substances": ["leather", "wood"],
            "features": [[0.5, 0.1, 0.1, 0.0, 0.2, 0.2], [0.3, 0.1, 0.1, 0.0, 0.2, floor]]}
    counts = breakdown([right, lost], floor)
    assert counts == {"cases": 2, "truth_at_floor": 1, "wrong": 1, "wrong_other_substance": 1,
                      "wrong_prior_favours_winner": 1, "wrong_truth_closer_in_colour": 1}
    split = cases_of([lost], floor)[0].features
    assert split[:, 5].tolist() == [0.2, 0.0] and split[:, 6].tolist() == [0.0, 1.0]
    base = hand_set()
    split_base = np.append(base, base[5] * floor)
    assert np.allclose(split @ split_base, np.asarray(lost["features"]) @ base)  # the same costs
    figures = models([right, lost] * 4, floor)  # four render groups per fold's worth of cases
    assert set(figures) == {"hand_set", "fitted", "fitted_split", "split_weights"}
    assert tuple(figures["split_weights"]) == SPLIT_TERMS
