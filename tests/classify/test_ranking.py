"""The ranking policy on hand-made evidence: each rule changes the order exactly where it should."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.classify.assignment import substance_vector
from photoshape_flow.classify.ranking import PartEvidence, RankingPolicy, rank_part, substance_first_order
from photoshape_flow.classify.substance_calibration import temper
from photoshape_flow.vocab import SUBSTANCE_LABELS

# materials 4 (wood), 9 (fabric), 12 (wood); head outputs are [background, 4, 9, 12]
POLICY = RankingPolicy((4, 9, 12), ("wood", "fabric", "wood"), substance_first=False)


def ids(evidence: PartEvidence, policy: RankingPolicy = POLICY, k: int = 3) -> list[int]:
    return [r.material_id for r in rank_part(evidence, policy, k).materials]


def test_the_head_is_weighted_by_the_substance_and_background_is_never_ranked() -> None:
    substance = np.zeros(len(SUBSTANCE_LABELS))
    substance[SUBSTANCE_LABELS.index("wood")], substance[SUBSTANCE_LABELS.index("fabric")] = 0.9, 0.1
    head = np.array([0.7, 0.1, 0.15, 0.05])
    ranked = rank_part(PartEvidence(head, substance), POLICY, 3).materials
    assert [r.material_id for r in ranked] == [4, 12, 9]
    assert ranked[0].score == pytest.approx(0.1 * 0.9) and ranked[0].probability == pytest.approx(0.1)
    assert ids(PartEvidence(head), k=2) == [9, 4]  # no substance weighting: the head alone
    assert 0 not in ids(PartEvidence(head), k=10)


def test_the_colour_likelihood_multiplies_in() -> None:
    ranked = rank_part(PartEvidence(np.array([0.1, 0.4, 0.35, 0.15]), color_weights=np.array([0.2, 1.0, 0.5])),
                       POLICY, 3).materials
    assert [r.material_id for r in ranked] == [9, 4, 12]
    assert ranked[0].score == pytest.approx(0.35) and ranked[1].score == pytest.approx(0.4 * 0.2)


def test_a_sharper_calibrated_substance_confidence_outweighs_the_head() -> None:
    head = np.array([0.1, 0.3, 0.5, 0.1])
    network = {"wood": 0.55, "fabric": 0.45}  # a mean of pixel opinions: right, but flat
    assert ids(PartEvidence(head, substance_vector(network)))[0] == 9  # the head's fabric overrules it
    assert ids(PartEvidence(head, substance_vector(temper(network, 0.25))))[0] == 4  # validation: trust it more


def test_substance_first_takes_the_substance_with_most_mass_then_its_best_material() -> None:
    head = np.array([0.1, 0.28, 0.34, 0.28])  # fabric's one material scores highest; wood holds more mass
    first = RankingPolicy(POLICY.materials, POLICY.material_substances, substance_first=True)
    assert ids(PartEvidence(head)) == [9, 4, 12]
    ranked = rank_part(PartEvidence(head), first, 3).materials
    assert [r.material_id for r in ranked] == [4, 9, 12] and ranked[0].score == pytest.approx(0.28)
    assert ids(PartEvidence(head), first, k=1) == [4]
    assert list(substance_first_order(np.array([0.5, 0.3, 0.2]), POLICY.material_substances)) == [0, 1, 2]
    assert substance_first_order(np.zeros(0), []).size == 0
    labels = ["wood", "fabric", "wood"]
    assert list(substance_first_order(np.array([0.28, 0.34, 0.28]), labels, "fabric")) == [1, 0, 2]
    assert list(substance_first_order(np.array([0.28, 0.34, 0.28]), labels, "metal")) == [0, 1, 2]
    assert list(substance_first_order(np.array([0.6, 0.0, 0.4]), labels, "fabric")) == [0, 2, 1]


def test_a_region_below_the_training_size_drops_the_head_and_takes_the_decided_substance() -> None:
    policy = RankingPolicy(POLICY.materials, POLICY.material_substances, min_region_fraction=0.005)
    head = np.array([0.1, 0.28, 0.34, 0.28])
    colours = np.array([1.0, 0.5, 0.8])
    large = rank_part(PartEvidence(head, color_weights=colours, region_fraction=0.01, substance="fabric"), policy, 3)
    assert large.head_used and [r.material_id for r in large.materials] == [4, 12, 9]  # mass: wood
    small = rank_part(PartEvidence(head, color_weights=colours, region_fraction=0.001, substance="fabric"),
                      policy, 3)
    assert not small.head_used
    assert [r.material_id for r in small.materials] == [9, 4, 12]  # the network's fabric, then colour
    assert small.materials[0].score == pytest.approx(0.5) and small.materials[0].probability == pytest.approx(0.34)
    # an unobserved part (no measured region) keeps the head
    assert rank_part(PartEvidence(head, region_fraction=None, substance="fabric"), policy, 3).head_used


def test_disabled_materials_are_not_ranked_and_lend_no_substance_mass() -> None:
    head = np.array([0.1, 0.28, 0.34, 0.28])
    policy = RankingPolicy(POLICY.materials, POLICY.material_substances, enabled=frozenset({4, 9}))
    assert ids(PartEvidence(head), policy) == [9, 4]  # 12 gone; wood's mass is 4's alone, fabric wins


def test_the_posterior_normalises_scores_over_enabled_materials() -> None:
    """Scores are products of experts (tiny); the posterior is the same order summing to 1 over enabled ones."""
    substance = np.zeros(len(SUBSTANCE_LABELS))
    substance[SUBSTANCE_LABELS.index("wood")], substance[SUBSTANCE_LABELS.index("fabric")] = 0.9, 0.1
    head = np.array([0.7, 0.1, 0.15, 0.05])  # scores 0.09, 0.015, 0.045: sum 0.15
    ranked = rank_part(PartEvidence(head, substance), POLICY, 3).materials
    assert [r.posterior for r in ranked] == pytest.approx([0.6, 0.3, 0.1])
    assert sum(r.posterior for r in ranked) == pytest.approx(1.0)
    only = RankingPolicy((4, 9, 12), ("wood", "fabric", "wood"), substance_first=False, enabled=frozenset({4, 9}))
    kept = rank_part(PartEvidence(head, substance), only, 3).materials
    assert {r.material_id: r.posterior for r in kept} == pytest.approx({4: 0.09 / 0.105, 9: 0.015 / 0.105})
    vetoed = rank_part(PartEvidence(head, color_weights=np.zeros(3)), only, 3).materials
    assert [r.posterior for r in vetoed] == pytest.approx([0.5, 0.5])  # no evidence left: uniform, not certain


def test_reliability_bins_and_ece() -> None:
    from photoshape_flow.classify.reliability import reliability

    # 0.9-confident and right 9 of 10 times, 0.55-confident and right half the time: ECE 0.05 * 10/20
    conf = np.array([0.9] * 10 + [0.55] * 10)
    hit = np.array([True] * 9 + [False] + [True] * 5 + [False] * 5)
    out = reliability(conf, hit)
    assert [(b["lo"], b["count"], b["accuracy"]) for b in out.bins] == [(0.5, 10, 0.5), (0.9, 10, 0.9)]
    assert out.ece == pytest.approx(0.025) and out.accuracy == pytest.approx(0.7)
    assert reliability(np.array([1.0]), np.array([True])).ece == 0.0  # 1.0 falls in the last bin
    assert reliability(np.array([]), np.array([])).ece is None
