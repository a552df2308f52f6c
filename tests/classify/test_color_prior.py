"""The colour likelihood that joins the classifier's ranking, its material colours and its sigma."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.classify.color_prior import (
    MIN_SIGMA,
    color_likelihood,
    fit_color_sigma,
    material_lab_matrix,
    region_color_distances,
    rendered_material_labs,
)
from photoshape_flow.classify.dataset import RenderItem


def test_likelihood_prefers_the_nearest_colour_and_is_neutral_without_evidence() -> None:
    labs = material_lab_matrix([4, 9, 12], {4: np.array([50.0, 0, 0]), 12: np.array([50.0, 30, 0])})
    assert np.isnan(labs[1]).all()  # material 9 has no colour
    like = color_likelihood(np.array([52.0, 2, 0]), labs, sigma=10.0)
    assert like[0] > like[2] and like[0] == pytest.approx(np.exp(-8 / 200))
    assert like[1] == pytest.approx((like[0] + like[2]) / 2)  # unknown colour: neither favoured nor ruled out
    assert np.all(color_likelihood(None, labs, 10.0) == 1.0)
    assert np.all(color_likelihood(np.zeros(3), np.full((2, 3), np.nan), 10.0) == 1.0)
    # a sharper sigma separates the same two colours more
    sharp = color_likelihood(np.array([52.0, 2, 0]), labs, sigma=3.0)
    assert sharp[2] / sharp[0] < like[2] / like[0]


def test_sigma_fit_recovers_the_spread_of_a_gaussian_and_resists_outliers() -> None:
    rng = np.random.default_rng(0)
    distances = np.linalg.norm(rng.normal(0, 6.0, (20000, 3)), axis=1)
    assert fit_color_sigma(distances) == pytest.approx(6.0, rel=0.03)
    with_outliers = np.concatenate([distances, np.full(2000, 200.0)])
    assert fit_color_sigma(with_outliers) == pytest.approx(6.0, rel=0.15)
    assert fit_color_sigma([]) is None
    assert fit_color_sigma([0.0, 0.0]) == MIN_SIGMA


def _render(tmp_path: Path, name: str, colours: dict[int, tuple[int, int, int]]) -> RenderItem:
    """A 40x40 render: material id k fills a horizontal band with a flat sRGB colour."""
    ids = np.zeros((40, 40), np.uint16)
    rgb = np.full((40, 40, 3), 255, np.uint8)
    for row, (mid, colour) in enumerate(colours.items()):
        ids[row * 10:(row + 1) * 10, 5:35] = mid
        rgb[row * 10:(row + 1) * 10, 5:35] = colour
    cv2.imwrite(str(tmp_path / f"{name}.png"), rgb[..., ::-1])
    cv2.imwrite(str(tmp_path / f"{name}_ids.png"), ids)
    return RenderItem(tmp_path / f"{name}.png", tmp_path / f"{name}_ids.png", name)


def test_region_distances_measure_each_region_against_its_own_material(tmp_path: Path) -> None:
    red, grey = (200, 30, 30), (120, 120, 120)
    labs = {3: median_lab(np.array([[red]], np.uint8)), 7: median_lab(np.array([[grey]], np.uint8))}
    exact = _render(tmp_path, "a", {3: red, 7: grey})
    darker = _render(tmp_path, "b", {3: (150, 20, 20), 5: (0, 255, 0)})  # material 5 has no colour: skipped
    broken = RenderItem(tmp_path / "missing.png", tmp_path / "missing_ids.png", "c")
    distances = region_color_distances([exact, darker, broken], labs)
    assert len(distances) == 3
    assert distances[0] == pytest.approx(0, abs=1.0) and distances[1] == pytest.approx(0, abs=1.0)
    assert distances[2] > 10  # the darker red is far from the material's own colour
    assert len(region_color_distances([exact, darker], labs, limit=1)) == 2
    assert len(region_color_distances([exact], labs, min_fraction=0.5)) == 0  # regions too small


def test_a_materials_colour_is_the_median_of_its_regions_in_the_renders(tmp_path: Path) -> None:
    """Three renders show material 3 lit three ways: its colour is the middle one, whatever a preview said;
    material 7, seen in one render only, is left to its preview (too few regions)."""
    shades = [(180, 40, 40), (200, 30, 30), (230, 60, 50)]
    items = [_render(tmp_path, f"r{k}", {3: shade, **({7: (90, 90, 90)} if k == 0 else {})})
             for k, shade in enumerate(shades)]
    items.append(RenderItem(tmp_path / "missing.png", tmp_path / "missing_ids.png", "gone"))  # unreadable: skipped
    labs = rendered_material_labs(items)
    assert set(labs) == {3}
    expected = np.median([median_lab(np.array([[s]], np.uint8)) for s in shades], axis=0)
    assert labs[3] == pytest.approx(expected)
    assert set(rendered_material_labs(items, min_regions=1)) == {3, 7}
    assert rendered_material_labs(items, min_fraction=0.5) == {}  # every region below the share: none
