"""Fit by rendering on a generated scene: two boxes, analytic materials, three synthetic studios.

The "photo" is the scene rendered with known materials under a known envmap, exposed, at higher spp
and another resolution than the fit renders, and its part map is shifted by a pixel (the alignment
is never exact). The render loops of `fit.scene` must recover what made it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from tests.render.conftest import write_exr

from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit.appearance import Weights, to_lab
from photoshape_flow.fit.candidates import Candidate
from photoshape_flow.fit.scene import (
    FitScene,
    FrameRenderer,
    estimate_lighting,
    render_candidates,
    select_profiled,
)
from photoshape_flow.fit.select import rank_candidates
from photoshape_flow.render import Camera, EnvmapSpec, MaterialSpec
from photoshape_flow.render.specs import linear_to_srgb
from photoshape_flow.render.testing import box_part, normalise_to_unit_cube

pytestmark = pytest.mark.render

MATERIALS = {  # id -> (substance, albedo sRGB, roughness, metallic)
    1: ("fabric", (0.70, 0.15, 0.10), 0.9, 0.0),  # A: red fabric
    2: ("plastic", (0.10, 0.25, 0.70), 0.3, 0.0),  # blue plastic
    3: ("metal", (0.75, 0.75, 0.75), 0.25, 1.0),  # grey metal
    4: ("wood", (0.35, 0.20, 0.10), 0.6, 0.0),  # dark wood
    5: ("leather", (0.85, 0.55, 0.45), 0.5, 0.0),  # a lighter, pinker leather
    6: ("fabric", (0.85, 0.85, 0.80), 0.9, 0.0),  # off-white fabric
}
TRUTH = {1: 1, 2: 2}  # part index -> material id
EXPOSURE = 0.7
TRUE_ENVMAP = 12


def _spec(material_id: int | None) -> MaterialSpec | None:
    if material_id is None:
        return None
    substance, albedo, roughness, metallic = MATERIALS[material_id]
    return MaterialSpec(f"m{material_id}", substance,
                        params={"albedo": list(albedo), "roughness": roughness, "metallic": metallic}, scale=None)


def _studio(path: Path, column: int, colour: tuple[float, float, float]) -> EnvmapSpec:
    """A dim grey sky with one bright coloured soft box at `column` of a 16 x 32 lat-long map."""
    sky = np.full((16, 32, 3), 0.15, np.float32)
    sky[3:8, column:column + 5] = colour
    return EnvmapSpec(write_exr(path, sky))


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    pytest.importorskip("mitsuba")
    from photoshape_flow.render.renderer import Renderer

    folder = tmp_path_factory.mktemp("studios")
    studios = {10: _studio(folder / "cool-right.exr", 20, (3.0, 5.0, 9.0)),
               11: _studio(folder / "white-top.exr", 12, (6.0, 6.0, 6.0)),
               TRUE_ENVMAP: _studio(folder / "warm-left.exr", 4, (9.0, 6.0, 3.0))}  # the truth last
    mesh = normalise_to_unit_cube([box_part(1, (-0.3, 0.0, 0.0), (0.25, 0.45, 0.25)),
                                   box_part(2, (0.3, 0.0, 0.0), (0.25, 0.45, 0.25))])
    camera = Camera(math.radians(30), math.radians(20), 2.4, 45.0)
    renderer = Renderer()
    truth = [_spec(TRUTH[p.index]) for p in mesh.parts]
    photo_frame = FrameRenderer(renderer, 64, 32)
    photo = linear_to_srgb(EXPOSURE * photo_frame.render(mesh, truth, camera, studios[TRUE_ENVMAP]))
    photo = (photo * 255 + 0.5).astype(np.uint8)
    labels = np.roll(photo_frame.part_ids(mesh, camera), 1, axis=1)
    return renderer, mesh, camera, studios, photo, labels


def _fit_scene(scene, size: int = 48):  # type: ignore[no-untyped-def]
    import cv2

    renderer, mesh, camera, studios, photo, labels = scene
    photo = cv2.resize(photo, (size, size), interpolation=cv2.INTER_AREA)
    labels = cv2.resize(labels, (size, size), interpolation=cv2.INTER_NEAREST)
    return FrameRenderer(renderer, size, 4), FitScene.from_photo(mesh, camera, photo, labels, [1, 2])


def _rotatable(studios: dict[int, EnvmapSpec]) -> dict[int, Callable[[float], EnvmapSpec]]:
    return {e: (lambda rotation, path=spec.path: EnvmapSpec(path, rotation=rotation)) for e, spec in studios.items()}


def test_lighting_estimate_picks_the_photo_envmap_and_its_exposure(scene) -> None:  # type: ignore[no-untyped-def]
    frame, fit_scene = _fit_scene(scene)
    truth = [_spec(TRUTH[p.index]) for p in fit_scene.mesh.parts]
    best, exposure, loss, renders = estimate_lighting(frame, fit_scene, truth, _rotatable(scene[3]), 1, Weights())
    assert (best.envmap_id, renders) == (TRUE_ENVMAP, 3)
    assert exposure == pytest.approx(EXPOSURE, rel=0.15) and loss < 0.5


def test_the_true_material_scores_best_among_other_substances_and_colours(scene) -> None:  # type: ignore[no-untyped-def]
    """Even from a wrong exposure (the ranking's first materials lit it): each candidate is judged at its own
    best exposure for the whole photo, and the winners' exposure is the photo's."""
    frame, fit_scene = _fit_scene(scene)
    candidates = {i: [Candidate(mid, MATERIALS[mid][0], 1.0 / len(MATERIALS), "ranking")
                      for mid in sorted(MATERIALS, reverse=True)] for i in (1, 2)}
    renders = render_candidates(frame, fit_scene, {1: 6, 2: 6}, candidates, _spec, scene[3][TRUE_ENVMAP])
    assert len(renders.renders) == len(MATERIALS)  # both parts switch candidate in the same render
    measured, exposures, exposure = select_profiled(renders, fit_scene, candidates, 2.5 * EXPOSURE, Weights(), 0.3,
                                                    stops=2.0)
    assert exposure == pytest.approx(EXPOSURE, rel=0.15)
    assert {exposures[i][mid] for i, mid in TRUTH.items()} == {exposure}
    for index, material in TRUTH.items():
        ranked = rank_candidates(candidates[index], measured[index], prior_weight=0.3)
        assert ranked[0].candidate.material_id == material, (index, [(s.candidate.material_id, s.cost)
                                                                     for s in ranked])
        assert ranked[0].cost < 0.8 * ranked[1].cost


def test_lighting_estimate_recovers_the_rotation_also_after_screening(scene) -> None:  # type: ignore[no-untyped-def]
    frame, fit_scene = _fit_scene(scene)
    truth = [_spec(TRUTH[p.index]) for p in fit_scene.mesh.parts]
    studios = _rotatable(scene[3])
    best, _, _, renders = estimate_lighting(frame, fit_scene, truth, studios, 4, Weights())
    assert (best.envmap_id, best.rotation, renders) == (TRUE_ENVMAP, 0.0, 12)
    # screened: every envmap at 0 and pi, then only the best one at all four rotations
    best, _, _, renders = estimate_lighting(frame, fit_scene, truth, studios, 4, Weights(), keep=1)
    assert (best.envmap_id, best.rotation, renders) == (TRUE_ENVMAP, 0.0, 3 * 2 + 2)


def test_a_render_is_blended_with_the_photos_background_at_its_silhouette() -> None:
    """A thin part whose edge pixels the camera blended with a grey backdrop: the render (un-premultiplied,
    with coverage) shows the same edge once `exposed_lab` blends it with the photo's measured background."""
    size, colour, backdrop = 32, np.array([0.30, 0.20, 0.10]), np.array([0.8, 0.8, 0.8])
    coverage = np.zeros((size, size), np.float32)
    coverage[4:28, 14:17] = 1.0
    coverage[4:28, 13] = coverage[4:28, 17] = 0.5  # anti-aliased edges
    photo_linear = coverage[..., None] * colour + (1.0 - coverage[..., None]) * backdrop
    photo = np.round(linear_to_srgb(photo_linear) * 255).astype(np.uint8)
    labels = (coverage > 0).astype(np.int32)
    scene = FitScene.from_photo(None, None, photo, labels, [1], erode_pixels=0, foreground=labels > 0)
    np.testing.assert_allclose(scene.background, backdrop, atol=0.01)
    rgba = np.concatenate([np.where(coverage[..., None] > 0, colour, 0.0), coverage[..., None]], -1)
    blended = scene.exposed_lab(rgba.astype(np.float32), 1.0)
    edge = coverage == 0.5
    assert float(np.abs(blended[edge] - scene.photo_lab[edge]).max()) < 1.0  # CIELAB units
    unblended = to_lab(lt.exposed_srgb(rgba[..., :3], 1.0))
    assert float(np.abs(unblended[edge] - scene.photo_lab[edge]).max()) > 10.0
