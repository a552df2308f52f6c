"""Procedural SVBRDFs: deterministic, tileable, in range, written in the contributing.md format."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from photoshape_flow.demo import noise
from photoshape_flow.demo.material_catalogue import CATALOGUE, MAX_PER_SUBSTANCE, select_recipes
from photoshape_flow.demo.materials import generate_maps, write_material
from photoshape_flow.vocab import SUBSTANCES

RES = 128  # small maps keep the tests fast; patterns are resolution independent
RECIPES = [r for s in SUBSTANCES for r in CATALOGUE[s]]


def wraps_seamlessly(image: np.ndarray) -> bool:
    """Edge continuity along both axes: the wrap-around step (last row/column to the first) is no
    larger than the large steps inside the tile (99th percentile of interior neighbour differences)."""
    for axis in (0, 1):
        steps = np.abs(np.diff(image, axis=axis, append=image.take([0], axis=axis)))
        other = tuple(i for i in range(image.ndim) if i != axis)
        per_line = steps.mean(axis=other)  # mean step between line k and k+1; the last is the wrap
        interior, wrap = per_line[:-1], per_line[-1]
        if wrap > 1.25 * np.percentile(interior, 99) + 1e-9:
            return False
    return True


def test_seam_criterion_rejects_non_periodic_noise() -> None:
    rng = np.random.default_rng(0)
    walk = np.cumsum(np.cumsum(rng.standard_normal((RES, RES)), axis=0), axis=1)  # smooth but not periodic
    assert not wraps_seamlessly(walk)
    assert wraps_seamlessly(noise.spectral(rng, RES, beta=3.0, fmax=8))


@pytest.mark.parametrize("recipe", RECIPES, ids=lambda r: r.name)
def test_maps_tile_and_are_in_range(recipe) -> None:
    maps = generate_maps(recipe, seed=3, resolution=RES)
    assert maps.albedo.shape == (RES, RES, 3) and maps.normal.shape == (RES, RES, 3)
    for channel in (maps.albedo, maps.roughness, maps.metallic, maps.height):
        assert channel.min() >= 0.0 and channel.max() <= 1.0
    np.testing.assert_allclose(np.linalg.norm(maps.normal, axis=-1), 1.0, atol=1e-6)
    assert (maps.normal[..., 2] > 0).all()
    for name in ("albedo", "roughness", "height"):
        assert wraps_seamlessly(getattr(maps, name)), f"{recipe.name} {name} has a seam"
    assert wraps_seamlessly(maps.normal)
    expected_metal = 1.0 if recipe.pattern in ("brushed", "polished") else 0.0
    assert maps.metallic.mean() == expected_metal


def test_same_seed_same_maps_other_seed_other_maps() -> None:
    recipe = CATALOGUE["leather"][0]
    a, b = generate_maps(recipe, 0, RES), generate_maps(recipe, 0, RES)
    np.testing.assert_array_equal(a.albedo, b.albedo)
    np.testing.assert_array_equal(a.normal, b.normal)
    assert not np.array_equal(a.height, generate_maps(recipe, 1, RES).height)


def test_materials_are_distinguishable_but_substances_cohere() -> None:
    """Mean albedo/roughness separate materials; within a substance they stay in one family."""
    stats = {r.name: generate_maps(r, 0, 64) for r in select_recipes(MAX_PER_SUBSTANCE)}
    feats = {n: np.r_[m.albedo.mean(axis=(0, 1)), m.roughness.mean(), m.metallic.mean()] for n, m in stats.items()}
    names = sorted(feats)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            assert np.abs(feats[a] - feats[b]).max() > 0.03, f"{a} and {b} look the same"
    for substance in ("metal", "fabric"):
        rough = [feats[r.name][3] for r in CATALOGUE[substance] if r.pattern != "painted"]
        assert np.ptp(rough) < 0.35


def test_select_recipes_takes_first_k_per_substance() -> None:
    chosen = select_recipes(2)
    assert len(chosen) == 2 * len(SUBSTANCES)
    assert [r.name for r in chosen if r.substance == "wood"] == [r.name for r in CATALOGUE["wood"][:2]]
    with pytest.raises(ValueError):
        select_recipes(MAX_PER_SUBSTANCE + 1)


def test_written_folder(tmp_path: Path) -> None:
    recipe = CATALOGUE["wood"][0]
    folder = tmp_path / recipe.name
    paths = write_material(folder, recipe, seed=0, resolution=RES)
    side = json.loads((folder / "material.json").read_text())
    assert side == {
        "name": recipe.name,
        "substance": "wood",
        "scale": recipe.scale,
        "normal": "gl",
        "source": "photoshape_flow demo",
        "license": "CC0-1.0",
        "attribution": side["attribution"],
        "source_url": None,
    }
    albedo = cv2.imread(str(paths["albedo"]), cv2.IMREAD_UNCHANGED)
    height = cv2.imread(str(paths["height"]), cv2.IMREAD_UNCHANGED)
    assert albedo.shape == (RES, RES, 3) and albedo.dtype == np.uint8
    assert height.shape == (RES, RES) and height.dtype == np.uint16
    # normals decode back to unit-ish vectors pointing out of the surface
    n = cv2.imread(str(paths["normal"]))[..., ::-1].astype(np.float64) / 255.0 * 2 - 1
    assert (n[..., 2] > 0.5).all()
    # rewriting identical content leaves the files alone
    before = {p: p.stat().st_mtime_ns for p in folder.iterdir()}
    write_material(folder, recipe, seed=0, resolution=RES)
    assert before == {p: p.stat().st_mtime_ns for p in folder.iterdir()}
