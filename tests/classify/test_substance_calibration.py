"""Part-level temperature scaling of substance confidences (classify/substance_calibration.py)."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.classify.substance_calibration import (
    MIN_PARTS,
    fit_temperature,
    nll,
    part_calibration_set,
    temper,
)
from photoshape_flow.vocab import SUBSTANCES


def _softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


def test_temper_sharpens_or_flattens_but_keeps_the_winner() -> None:
    probs = {"leather": 0.4, "fabric": 0.3, "wood": 0.2, "metal": 0.1, "plastic": 0.0, "background": 0.7}
    sharp, flat, same = temper(probs, 0.5), temper(probs, 2.0), temper(probs, 1.0)
    assert set(sharp) == set(SUBSTANCES)  # background and other keys dropped
    for out in (sharp, flat, same):
        assert sum(out.values()) == pytest.approx(1.0)
        assert max(out, key=out.get) == "leather"
        assert out["plastic"] == 0.0  # impossible stays impossible
    assert same["leather"] == pytest.approx(0.4)
    assert sharp["leather"] > 0.4 > flat["leather"]
    # T = 0.5 squares the probabilities: 0.16 / (0.16 + 0.09 + 0.04 + 0.01)
    assert sharp["leather"] == pytest.approx(0.16 / 0.30)
    assert temper(None, 0.5) == {} and temper({}, 2.0) == {}


def test_fit_temperature_recovers_the_miscalibration() -> None:
    rng = np.random.default_rng(0)
    logits = rng.normal(0.0, 2.0, size=(6000, len(SUBSTANCES)))
    true_posterior = _softmax(logits)
    truth = np.array([rng.choice(len(SUBSTANCES), p=p) for p in true_posterior])
    # a network whose confidences are too flat: p = softmax(0.4 z), so p^(1/0.4) is the true posterior
    under_confident = _softmax(0.4 * logits)
    assert fit_temperature(under_confident, truth) == pytest.approx(0.4, rel=0.08)
    over_confident = _softmax(3.0 * logits)
    assert fit_temperature(over_confident, truth) == pytest.approx(3.0, rel=0.08)
    assert fit_temperature(true_posterior, truth) == pytest.approx(1.0, rel=0.08)


def test_fit_temperature_needs_enough_parts() -> None:
    probs = np.full((MIN_PARTS - 1, len(SUBSTANCES)), 1.0 / len(SUBSTANCES))
    assert fit_temperature(probs, np.zeros(MIN_PARTS - 1, int)) is None
    with pytest.raises(ValueError):
        fit_temperature(probs, np.zeros(3, int))


def test_calibration_set_reads_parts_and_their_true_substance() -> None:
    h = w = 20
    part_ids = np.zeros((h, w), np.int64)
    part_ids[2:10, 2:18] = 1  # a wooden part
    part_ids[12:18, 2:18] = 2  # a metal part
    part_ids[0, 0] = 3  # a one-pixel part: below min_fraction, ignored
    substance_ids = np.zeros((h, w), np.int64)
    substance_ids[part_ids == 1] = 1 + SUBSTANCES.index("wood")
    substance_ids[part_ids == 2] = 1 + SUBSTANCES.index("metal")
    probs = np.full((1 + len(SUBSTANCES), h, w), 0.1)
    probs[1 + SUBSTANCES.index("wood")][part_ids == 1] = 0.6  # the network is right on part 1
    probs[1 + SUBSTANCES.index("leather")][part_ids == 2] = 0.6  # and wrong on part 2
    probs /= probs.sum(axis=0, keepdims=True)
    calibration = part_calibration_set([(probs, part_ids, substance_ids)])
    assert len(calibration) == 2
    assert calibration.truth.tolist() == [SUBSTANCES.index("wood"), SUBSTANCES.index("metal")]
    assert calibration.probs.argmax(axis=1).tolist() == [SUBSTANCES.index("wood"), SUBSTANCES.index("leather")]
    np.testing.assert_allclose(calibration.probs.sum(axis=1), 1.0)
    with pytest.raises(ValueError):
        part_calibration_set([(probs, part_ids[:10], substance_ids)])


def test_nll_is_log_of_the_classes_for_uniform_and_drops_when_sharpening_right_answers() -> None:
    uniform = np.full((4, len(SUBSTANCES)), 1.0 / len(SUBSTANCES))
    assert nll(uniform, [0, 1, 2, 3]) == pytest.approx(np.log(len(SUBSTANCES)))
    right = np.tile([0.4, 0.15, 0.15, 0.15, 0.15], (3, 1))
    assert nll(right, [0, 0, 0], temperature=0.5) < nll(right, [0, 0, 0]) == pytest.approx(-np.log(0.4))
