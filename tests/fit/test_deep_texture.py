"""The fit's deep texture term, through the real ImageNet backbone: patterns of one colour and contrast."""

from __future__ import annotations

import numpy as np
import pytest

from photoshape_flow.classify.feature_maps import FeatureMaps
from photoshape_flow.fit.appearance import appearance, terms, to_lab
from photoshape_flow.fit.deep_texture import deep_distance, deep_stats
from photoshape_flow.fit.scene import with_deep

SIZE = 96
WIDTH = 6  # px per stripe: a grain coarser than the fit's blur and the backbone's first strides


@pytest.fixture(scope="module")
def maps() -> FeatureMaps:
    return FeatureMaps("efficientnet-lite0")


def _stripes(vertical: bool, shift: int = 0) -> np.ndarray:
    """Brown and beige stripes `WIDTH` px wide (a grain): the same colours, contrast and gradients either way."""
    line = ((np.arange(SIZE) + shift) // WIDTH) % 2
    pattern = np.broadcast_to(line[None, :] if vertical else line[:, None], (SIZE, SIZE))
    return np.where(pattern[..., None] > 0, [0.75, 0.60, 0.45], [0.45, 0.30, 0.18]).astype(np.float32)


def _region() -> np.ndarray:
    mask = np.zeros((SIZE, SIZE), bool)
    mask[16:80, 16:80] = True
    return mask


def test_the_deep_term_tells_a_grains_direction_which_the_other_terms_cannot(maps: FeatureMaps) -> None:
    """Vertical against horizontal stripes of the same two colours: CIELAB mean and std and the gradient
    statistics are identical (the pattern is only turned), the deep term is not; a shift of the same
    pattern by a stripe (what misalignment does) costs far less than the turn."""
    mask = _region()
    horizontal, vertical, shifted = _stripes(False), _stripes(True), _stripes(False, shift=3)
    stats = {name: with_deep(appearance(to_lab(image), mask), maps.maps(image), mask)  # type: ignore[arg-type]
             for name, image in (("h", horizontal), ("v", vertical), ("s", shifted))}
    turned, moved = terms(stats["h"], stats["v"]), terms(stats["h"], stats["s"])
    assert turned[:4] == pytest.approx(np.zeros(4), abs=0.05)  # colour, contrast, gradient, highlight
    assert terms(stats["h"], stats["h"])[4] == pytest.approx(0.0, abs=1e-9)
    assert turned[4] > 0.05 and turned[4] > 3.0 * moved[4], (turned, moved)


def test_a_parts_deep_statistics_ignore_the_pixels_of_the_rest_of_the_frame_at_its_centre(maps: FeatureMaps) -> None:
    """The maps read the whole frame once; a part's statistics are pooled over its own cells, so changing
    another region far away leaves them (nearly: receptive fields reach across cell borders) unchanged,
    and a region smaller than a cell of the deepest tap has none."""
    image = _stripes(False)
    mask = np.zeros((SIZE, SIZE), bool)
    mask[8:40, 8:40] = True
    other = image.copy()
    other[60:, 60:] = [0.1, 0.5, 0.9]
    a, b = deep_stats(maps.maps(image), mask), deep_stats(maps.maps(other), mask)
    assert a is not None and b is not None
    assert deep_distance(a, b) < 1e-3
    tiny = np.zeros((SIZE, SIZE), bool)
    tiny[0, 0] = True
    assert deep_stats(maps.maps(image), tiny) is None
    assert maps.maps(image)[0].shape == (maps.maps(image)[0].shape[0], SIZE // 2, SIZE // 2)  # stride 4 of 2x


def test_feature_maps_are_deterministic(maps: FeatureMaps) -> None:
    image = _stripes(True)
    first, second = maps.maps(image), FeatureMaps("efficientnet-lite0").maps(image)
    assert all(np.array_equal(x, y) for x, y in zip(first, second, strict=True))


def test_the_fit_measures_the_deep_term_once_per_render_and_it_picks_the_grain(maps: FeatureMaps) -> None:
    """A photo of vertical stripes; two candidate renders of the same colours, one striped the same way,
    one across: the colour terms tie, the deep term (read once per render, whatever the exposure grid)
    ranks the right one first. Without a backbone the deep column is 0."""
    from photoshape_flow.fit import lighting as lt
    from photoshape_flow.fit.appearance import Weights
    from photoshape_flow.fit.candidates import Candidate
    from photoshape_flow.fit.scene import CandidateRenders, FitScene, profiled_terms

    mask = _region()
    ids = np.where(mask, 1, 0).astype(np.int32)
    photo = _stripes(True)
    linear = lt.photo_linear((photo * 255 + 0.5).astype(np.uint8))
    reads: list[int] = []

    def counted(image: np.ndarray) -> list[np.ndarray]:
        reads.append(1)
        return maps.maps(image)

    renders = [np.concatenate([lt.photo_linear((image * 255 + 0.5).astype(np.uint8)), np.ones((SIZE, SIZE, 1))],
                              axis=-1).astype(np.float32) for image in (_stripes(True, shift=2), _stripes(False))]
    plan = CandidateRenders(renders, {1: {7: 0, 8: 1}}, ids)
    candidates = {1: [Candidate(7, "wood", 0.5, "ranking"), Candidate(8, "wood", 0.5, "ranking")]}
    grid = (0.84, 1.0, 1.19)
    for features, deep_weight in ((counted, 1.0), (None, 0.0)):
        scene = FitScene(None, None, linear, to_lab(lt.exposed_srgb(linear, 1.0)), {1: mask}, features=features)
        measured, _, _ = profiled_terms(plan, scene, candidates, 1.0, Weights(deep=deep_weight), 0.0, grid)
        right, across = measured[1][7], measured[1][8]
        assert right is not None and across is not None
        if features is None:
            assert right[4] == across[4] == 0.0
        else:
            assert right[4] < 0.5 * across[4], (right, across)
            assert len(reads) == 1 + len(renders)  # the photo once, each render once (not per exposure)
