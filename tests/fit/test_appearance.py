"""The pure parts of fit by rendering: appearance distance, exposure, candidates, render plan, ranking."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit.appearance import Region, Weights, appearance, distance, erode, terms, to_lab
from photoshape_flow.fit.candidates import Candidate, RankedRow, part_candidates
from photoshape_flow.fit.select import rank_candidates, render_slots, scores_of


def _square(size: int = 40, lo: int = 8, hi: int = 32) -> np.ndarray:
    mask = np.zeros((size, size), bool)
    mask[lo:hi, lo:hi] = True
    return mask


def _flat(rgb: tuple[int, int, int], size: int = 40) -> np.ndarray:
    return np.broadcast_to(np.array(rgb, np.uint8), (size, size, 3)).copy()


def test_a_few_highlights_are_the_highlight_terms_not_the_colours() -> None:
    """A glossy region (5% of pixels a bright highlight on a slightly darker base) against a matte one
    of the same mean L*: the colour term barely sees it, the highlight term (99th percentile above the
    median) sees a 40-L* tail and is the largest of the four."""
    rng = np.random.default_rng(1)
    lab = np.zeros((40, 40, 3), np.float32)
    matte, glossy = lab.copy(), lab.copy()
    matte[..., 0] = 50.0 + rng.uniform(-2.0, 2.0, (40, 40))
    glossy[..., 0] = np.where(rng.random((40, 40)) < 0.05, 90.0, 48.0)
    mask = _square()
    a, b = appearance(matte, mask), appearance(glossy, mask)
    assert a is not None and b is not None
    color, contrast, gradient, highlight, deep = terms(a, b)
    assert deep == 0.0  # no backbone statistics measured
    assert color < 0.3 and highlight > 3.0 and highlight > max(contrast, gradient)
    assert b.highlight[1] == pytest.approx(42.0) and a.highlight[1] < 2.5


def test_distance_is_zero_for_itself_and_tolerates_a_shifted_region() -> None:
    rng = np.random.default_rng(0)
    image = np.clip(_flat((150, 90, 60)).astype(int) + rng.integers(-20, 20, (40, 40, 1)), 0, 255).astype(np.uint8)
    lab, mask = to_lab(image), _square()
    a = appearance(lab, mask)
    assert a is not None and distance(a, a) == 0.0
    shifted = appearance(lab, np.roll(mask, 3, axis=1))  # a misaligned region of the same material
    other = appearance(to_lab(_flat((60, 90, 150))), mask)
    assert shifted is not None and other is not None
    assert distance(a, shifted) < 0.1 < 1.0 < distance(a, other)


def test_gradient_statistics_separate_texture_from_a_flat_region_of_the_same_mean() -> None:
    yy, xx = np.mgrid[:40, :40]
    stripes = np.where((xx // 2) % 2 == 0, 90, 210).astype(np.uint8)
    striped = np.repeat(stripes[..., None], 3, axis=2)
    flat = _flat((150, 150, 150))
    mask = _square()
    a, b = appearance(to_lab(striped), mask), appearance(to_lab(flat), mask)
    assert a is not None and b is not None
    only_mean = Weights(color=1.0, contrast=0.0, gradient=0.0)
    only_gradient = Weights(color=0.0, contrast=0.0, gradient=1.0)
    assert distance(a, b, only_mean) < 0.5 * distance(a, b, only_gradient)
    assert a.gradient[0] > 5 * b.gradient[0] + 1


def test_a_region_derived_once_reads_every_image_as_its_mask_does() -> None:
    """The fit derives a frame's regions once (`Region.of`) and reads every candidate render and
    exposure in them: each image's statistics equal those read through the plain mask, on odd-sized
    frames and on a sliver whose half-size mask is empty."""
    rng = np.random.default_rng(3)
    blob = np.zeros((37, 41), bool)
    blob[5:30, 7:33] = rng.random((25, 26)) < 0.9
    sliver = np.zeros((37, 41), bool)
    sliver[11, 3:39] = True  # one row: half-size nearest-neighbour sampling misses it
    for mask in (blob, sliver):
        region = Region.of(mask)
        assert sliver is not mask or region.coarse is None
        for _ in range(3):
            lab = to_lab(rng.integers(0, 255, (37, 41, 3), dtype=np.uint8))
            a, b = appearance(lab, region), appearance(lab, mask)
            assert a is not None and b is not None
            assert all(np.array_equal(x, y) for x, y in zip((a.lab_mean, a.lab_std, a.gradient, a.highlight),
                                                             (b.lab_mean, b.lab_std, b.gradient, b.highlight),
                                                             strict=True))


def test_small_regions_have_no_statistics_and_erosion_keeps_something() -> None:
    tiny = np.zeros((10, 10), bool)
    tiny[4:6, 4:6] = True
    assert appearance(to_lab(_flat((1, 2, 3), 10)), tiny) is None
    assert erode(tiny, 2).sum() == 4  # nothing would be left: the region stays
    assert erode(_square(), 2).sum() == 20 * 20


def test_exposure_is_the_least_squares_scale_of_the_part_means() -> None:
    rendered = {1: (np.array([0.2, 0.1, 0.05]), 100), 2: (np.array([0.05, 0.1, 0.3]), 50)}
    photo = {k: (2.5 * v, n) for k, (v, n) in rendered.items()}
    assert lt.exposure(rendered, photo) == pytest.approx(2.5)
    assert lt.exposure(rendered, {}) == 1.0
    assert lt.exposure({1: (np.ones(3), 1)}, {1: (np.full(3, 1e6), 1)}) == lt.EXPOSURE_RANGE[1]
    h = lt.Hypothesis(1, 0.0)
    assert lt.best([(h, 1.0, np.inf), (lt.Hypothesis(2, 0.5), 2.0, 0.3), (h, 1.0, 0.4)])[0].envmap_id == 2
    with pytest.raises(ValueError, match="no lighting hypothesis"):
        lt.best([(h, 1.0, np.inf)])


def test_candidates_are_the_ranking_the_nearest_colour_per_substance_and_untrained_materials() -> None:
    substance = {1: "wood", 2: "wood", 3: "metal", 4: "fabric", 5: "fabric", 9: "plastic"}
    labs = {1: np.array([40.0, 10, 20]), 2: np.array([60.0, 5, 10]), 3: np.array([70.0, 0, 0]),
            4: np.array([30.0, 40, 20]), 5: np.array([55.0, 0, 5])}
    ranked = [RankedRow(2, "wood", 0.6), RankedRow(3, "metal", 0.2), RankedRow(1, "wood", 0.2),
              RankedRow(7, "leather", 0.9)]  # 7: disabled since, never a candidate
    got = part_candidates(ranked, 2, substance, labs, np.array([56.0, 1, 6]), untrained={9, 7}, floor=0.05)
    assert [(c.material_id, c.source) for c in got] == [(2, "ranking"), (3, "ranking"), (5, "colour"), (9, "new")]
    assert got[0].prior == pytest.approx(0.75) and got[2].prior == 0.05
    assert got[0].prior_cost < got[2].prior_cost


def test_slots_switch_every_part_at_once_and_costs_rank_by_distance_and_prior() -> None:
    a, b, c = (Candidate(i, "wood", p, "ranking") for i, p in ((1, 0.5), (2, 0.3), (3, 0.2)))
    assert render_slots({10: [a, b, c], 20: [b]}) == [{10: 1, 20: 2}, {10: 2, 20: 2}, {10: 3, 20: 2}]
    ranked = rank_candidates([a, b, c], {1: 1.0, 2: 0.2, 3: None}, prior_weight=0.0)
    assert [s.candidate.material_id for s in ranked] == [2, 3, 1]  # 3 unmeasured: the mean distance, 0.6
    assert ranked[1].distance is None and ranked[1].cost == pytest.approx(0.6)
    assert [s.candidate.material_id for s in rank_candidates([a, b], {1: 1.0, 2: 0.9}, prior_weight=1.0)] == [1, 2]
    scores = scores_of(ranked)
    assert sum(scores) == pytest.approx(1.0) and scores == sorted(scores, reverse=True)
