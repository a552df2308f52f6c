"""Substance per aligned part: majority of non-background argmax, confidence, unobserved parts."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.vocab import SUBSTANCE_LABELS


def _probs(label_map: np.ndarray, sharp: float = 0.9) -> np.ndarray:
    """One-hot-ish probabilities: `sharp` on the given label, the rest spread evenly."""
    n = len(SUBSTANCE_LABELS)
    probs = np.full((n, *label_map.shape), (1 - sharp) / (n - 1), np.float32)
    for k in range(n):
        probs[k][label_map == k] = sharp
    return probs


def test_majority_wins_and_confidence_is_conditional_mean() -> None:
    parts = np.zeros((4, 6), np.int32)
    parts[:, :3] = 1
    parts[:, 3:] = 2
    labels = np.zeros((4, 6), np.int64)
    labels[:, :3] = SUBSTANCE_LABELS.index("wood")
    labels[0, :2] = SUBSTANCE_LABELS.index("metal")  # 2 of 12 pixels disagree
    labels[:, 3:] = SUBSTANCE_LABELS.index("fabric")
    labels[:2, 3:] = 0  # background votes are ignored, fabric still wins part 2
    results = part_substances(parts, _probs(labels), [1, 2, 3])

    by_index = {r.part_index: r for r in results}
    assert [r.part_index for r in results] == [1, 2, 3]
    wood = by_index[1]
    assert wood.observed and wood.substance == "wood" and wood.pixel_count == 12
    assert wood.votes["wood"] == 10 and wood.votes["metal"] == 2
    # conditional probability of wood: 0.9/(0.9+4*0.02) on 10 pixels, 0.02/(1-0.02) on 2
    expected = (10 * 0.9 / 0.98 + 2 * 0.02 / 0.98) / 12
    assert wood.confidence == pytest.approx(expected, rel=1e-5)
    assert sum(wood.probs.values()) == pytest.approx(1.0, rel=1e-5)

    fabric = by_index[2]
    assert fabric.substance == "fabric" and fabric.votes["fabric"] == 6
    assert fabric.background_prob is not None and fabric.background_prob > 0.4

    missing = by_index[3]
    assert not missing.observed and missing.substance is None and missing.confidence is None
    assert missing.pixel_count == 0


def test_all_background_votes_fall_back_to_substance_argmax() -> None:
    parts = np.ones((3, 3), np.int32)
    probs = np.zeros((6, 3, 3), np.float32)
    probs[0] = 0.7
    probs[SUBSTANCE_LABELS.index("leather")] = 0.2
    probs[SUBSTANCE_LABELS.index("plastic")] = 0.1
    (result,) = part_substances(parts, probs, [1])
    assert result.observed and result.substance == "leather"
    assert result.confidence == pytest.approx(2 / 3, rel=1e-5)


def test_min_pixels_marks_tiny_parts_unobserved() -> None:
    parts = np.zeros((5, 5), np.int32)
    parts[0, 0] = 4
    labels = np.full((5, 5), SUBSTANCE_LABELS.index("metal"))
    (result,) = part_substances(parts, _probs(labels), [4], min_pixels=2)
    assert not result.observed and result.pixel_count == 1


def test_shape_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError):
        part_substances(np.zeros((4, 4), np.int32), np.zeros((6, 5, 5), np.float32), [1])
