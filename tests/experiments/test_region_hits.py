"""The experiments' one region scorer (`experiments.common.region_hits`, `interval`) on a classifier whose
answers are known: the hits are the ranks and substances it was given, the interval resamples photos."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from experiments.common import HIT_COLUMNS, interval, region_hits

from photoshape_flow.vocab import SUBSTANCE_LABELS

MATERIALS = [10, 11, 12, 13, 14, 15, 16]
SUBSTANCES = ["wood", "wood", "fabric", "fabric", "leather", "metal", "metal"]


class Ranked:
    """Scores each region's materials by a fixed order (first = best) and says `head` as its substance."""

    materials, material_substances = MATERIALS, SUBSTANCES

    def __init__(self, order: list[int], head: str):
        self.order, self.head = order, head

    def predict(self, image, masks):  # type: ignore[no-untyped-def]
        mats = np.zeros((len(masks), len(MATERIALS) + 1))
        for rank, mid in enumerate(self.order):
            mats[:, 1 + MATERIALS.index(mid)] = len(self.order) - rank
        subs = np.zeros((len(masks), len(SUBSTANCE_LABELS)))
        subs[:, SUBSTANCE_LABELS.index(self.head)] = 1.0
        return mats / mats.sum(1, keepdims=True), subs


def test_hits_follow_the_rank_of_the_true_material_and_the_substances() -> None:
    case = SimpleNamespace(image=None, masks=[None, None, None], truth=[11, 16, 99])  # 99: unknown, left out
    hits = region_hits(Ranked([10, 12, 13, 14, 15, 11, 16], head="wood"), [case], MATERIALS)
    assert hits.shape == (2, len(HIT_COLUMNS))
    col = {name: i for i, name in enumerate(HIT_COLUMNS)}
    (first, second) = hits
    assert first[col["material"]] == 11 and first[col["top1"]] == 0 and first[col["top5"]] == 0  # 6th
    assert first[col["substance_top"]] == 1 and first[col["substance_head"]] == 1  # wood on top, head wood
    assert second[col["top5"]] == 0 and second[col["substance_head"]] == 0
    assert second[col["substance_mass"]] == 0  # fabric holds the most mass (ranks 2-3), not metal
    # only the enabled materials compete: without 10, 12-15 the true 11 is first
    again = region_hits(Ranked([10, 12, 13, 14, 15, 11, 16], head="wood"), [case], [11, 16])
    assert again[0, col["top1"]] == 1 and again[1, col["top1"]] == 0 and again[1, col["top5"]] == 1


def test_interval_resamples_whole_groups() -> None:
    values = np.array([1.0, 1.0, 0.0, 0.0])
    mean, low, high = interval(values, np.array([0, 0, 1, 1]), np.random.default_rng(0))
    assert mean == 0.5 and low == 0.0 and high == 1.0  # two photos: all of one, all of the other, or both
    assert interval(values, np.array([0, 0, 0, 0]), np.random.default_rng(0)) == [0.5, 0.5, 0.5]
    assert interval(np.array([]), np.array([], int), np.random.default_rng(0)) is None
