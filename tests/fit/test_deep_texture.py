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
