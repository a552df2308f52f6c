"""A pair as the fit sees it (photo, aligned regions, shape, camera) and the renders that score it; no database.

`FrameRenderer` renders a shape at a pair's camera in the exemplar's frame (the tight square crop of
the silhouette, as fine alignment frames the part map). `estimate_lighting` and `measure_candidates`
are the two render loops of the fit stage; they take render specs and return numbers, so tests run
them on generated scenes and `fitting.fit` on the database's pairs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import cv2
import numpy as np

from photoshape_flow.align.partmap import resize_labels, zoom_to_fit
from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit.appearance import (
    Appearance,
    Region,
    Weights,
    appearance,
    erode,
    soften,
    terms,
    to_lab,
    weigh,
)
from photoshape_flow.fit.candidates import Candidate
from photoshape_flow.fit.deep_texture import deep_stats
from photoshape_flow.fit.select import rank_candidates, render_slots
from photoshape_flow.imaging.squares import crop_square, square_box
from photoshape_flow.render.gradients import GradientScene

MIN_BACKGROUND = 12  # background pixels needed to measure the photo's background colour
OVERSAMPLE = 1.25  # render larger than the frame, then crop the silhouette's square (as fine alignment)


class FrameRenderer:
    """A shape rendered at a camera, cropped like the exemplar: the silhouette's square at `size` pixels."""

    def __init__(self, renderer: Any, size: int, spp: int):
        self.renderer = renderer
        self.size = size
        self.spp = spp
        self._frames: dict[tuple[int, Any], tuple[Any, tuple[int, int, int], np.ndarray]] = {}

    @property
    def render_size(self) -> int:
        return int(math.ceil(self.size * OVERSAMPLE))

    def _frame(self, mesh: Any, camera: Any) -> tuple[Any, tuple[int, int, int], np.ndarray]:
        key = (id(mesh), camera)
        if key not in self._frames:
            zoomed = zoom_to_fit(mesh, camera)
            ids = self.renderer.part_ids(mesh, zoomed, size=self.render_size)
            box = square_box(ids > 0)
            if box is None:
                raise ValueError("the shape is not visible at the pair's camera")
            # one frame kept: pairs are fitted one after the other
            self._frames = {key: (zoomed, box, resize_labels(crop_square(ids, *box, fill=0), self.size))}
        return self._frames[key]

    def part_ids(self, mesh: Any, camera: Any) -> np.ndarray:
        """(size, size) part indices of the shape in the frame (0 = background)."""
        return self._frame(mesh, camera)[2]

    def render_ids(self, mesh: Any, camera: Any) -> np.ndarray:
        """(render_size, render_size) part indices of the whole render before the crop: what
        `gradient_scene` renders (a loss on it needs no differentiable crop and resize)."""
        return self.renderer.part_ids(mesh, self._frame(mesh, camera)[0], size=self.render_size)

    def gradient_scene(self, mesh: Any, materials: Sequence[Any], camera: Any, envmap: Any,
                       max_depth: int = 3) -> Any:
        """The renderer's scene at the frame's camera with differentiable tints and roughness
        (`render.gradients.GradientScene`, a context manager), uncropped at `render_size`."""
        zoomed = self._frame(mesh, camera)[0]
        return GradientScene(self.renderer, mesh, materials, zoomed, envmap, self.render_size, max_depth)

    def render_rgba(self, mesh: Any, materials: Sequence[Any], camera: Any, envmap: Any,
                    uv_transforms: Sequence[Any] | None = None) -> np.ndarray:
        """(size, size, 4): linear radiance in the frame, un-premultiplied (background 0), and coverage.

        Un-premultiplied so that a thin part's edge pixels carry the part's colour, not a blend with
        the (black) background; the coverage lets `FitScene.exposed_lab` blend them with the photo's
        own background instead, as the camera blended the photo's.
        `uv_transforms` (one per mesh part, None: the material's own scale) as `Renderer.beauty`.
        """
        zoomed, box, _ = self._frame(mesh, camera)
        result = self.renderer.beauty(mesh, list(materials), zoomed, envmap, size=self.render_size, spp=self.spp,
                                      background="transparent", seed=0, uv_transforms=uv_transforms)
        size = (self.size, self.size)
        rgb = cv2.resize(crop_square(result.hdr, *box, fill=0.0), size, interpolation=cv2.INTER_AREA)
        alpha = cv2.resize(crop_square(result.alpha, *box, fill=0.0), size, interpolation=cv2.INTER_AREA)
        un = np.where(alpha[..., None] > 0.05, rgb / np.maximum(alpha, 0.05)[..., None], 0.0)
        return np.concatenate([un, np.clip(alpha, 0.0, 1.0)[..., None]], axis=-1).astype(np.float32)

    def render(self, mesh: Any, materials: Sequence[Any], camera: Any, envmap: Any,
               uv_transforms: Sequence[Any] | None = None) -> np.ndarray:
        """(size, size, 3) linear radiance in the frame, un-premultiplied (background 0)."""
        return self.render_rgba(mesh, materials, camera, envmap, uv_transforms)[..., :3]


@dataclass
class FitScene:
    """What a render is compared with: the photo at the frame's size and each observed part's region in it."""

    mesh: Any
    camera: Any
    photo_linear: np.ndarray  # (size, size, 3)
    photo_lab: np.ndarray
    masks: dict[int, np.ndarray]  # observed part index -> region of the photo (eroded)
    blur: float = 0.0  # Gaussian sigma (pixels) applied to the photo and to every render (`soften`)
    background: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))  # the photo's, linear RGB
    # sRGB frame -> backbone feature maps (`classify.feature_maps`): with it, regions carry deep texture
    # statistics (`fit.deep_texture`); None: the deep term is 0
    features: Callable[[np.ndarray], list[np.ndarray]] | None = None

    @classmethod
    def from_photo(cls, mesh: Any, camera: Any, photo_srgb: np.ndarray, labels: np.ndarray,
                   indices: Sequence[int], erode_pixels: int = 1, min_pixels: int = 12,
                   blur: float = 0.0, foreground: np.ndarray | None = None,
                   features: Callable[[np.ndarray], list[np.ndarray]] | None = None) -> FitScene:
        """`photo_srgb` uint8, `labels` (part index per pixel) and the photo's `foreground` at the same size.

        A part's region is its labels inside the foreground (the aligned map spills onto the
        background around thin parts), eroded; parts left with fewer than `min_pixels` are dropped.
        The photo's background colour is the median of its pixels away from the foreground (white
        when there are too few): renders are blended with it at their silhouette (`exposed_lab`).
        """
        inside = np.ones(labels.shape, bool) if foreground is None else np.asarray(foreground, bool)
        masks = {}
        for index in indices:
            region = erode((labels == index) & inside, erode_pixels)
            if int(region.sum()) >= min_pixels:
                masks[index] = region
        unblurred = lt.photo_linear(photo_srgb)
        away = cv2.dilate(inside.astype(np.uint8), np.ones((7, 7), np.uint8)) == 0
        background = np.median(unblurred[away], axis=0) if int(away.sum()) >= MIN_BACKGROUND else np.ones(3)
        linear = soften(unblurred, blur)
        return cls(mesh, camera, linear, to_lab(lt.exposed_srgb(linear, 1.0)), masks, blur,
                   np.asarray(background, np.float32), features)

    def render(self, frame: FrameRenderer, materials: Sequence[Any], envmap: Any) -> np.ndarray:
        """A render of the scene's shape in the frame: (size, size, 4) un-premultiplied linear RGB and coverage."""
        return frame.render_rgba(self.mesh, materials, self.camera, envmap)

    def exposed_linear(self, rgba: np.ndarray, exposure: float | np.ndarray) -> np.ndarray:
        """A render (`render`) at `exposure` over the photo's background at the silhouette, softened like
        the photo: linear RGB, what `exposed_lab` converts."""
        alpha = rgba[..., 3:4]
        gain = np.asarray(exposure, np.float32)  # a factor, or per-channel factors (a white balance)
        return soften(rgba[..., :3] * (alpha * gain) + (1.0 - alpha) * self.background, self.blur)

    def exposed_lab(self, rgba: np.ndarray, exposure: float | np.ndarray) -> np.ndarray:
        """CIELAB of a render (`render`) as the photo would show it: at `exposure`, over the photo's
        background at the silhouette, softened like the photo.

        Like for like at the silhouette: the photo's edge pixels are its object blended with its
        background (coverage, lens, resize), so the render's are blended with the same colour, or a
        thin part (a leg, a frame bar) would be compared in two different mixtures.
        """
        return to_lab(lt.exposed_srgb(self.exposed_linear(rgba, exposure), 1.0))

    def deep_maps(self, rgba: np.ndarray, exposure: float | np.ndarray) -> list[np.ndarray] | None:
        """The backbone's feature maps of a render as the photo would show it (None without a backbone)."""
        if self.features is None:
            return None
        return self.features(lt.exposed_srgb(self.exposed_linear(rgba, exposure), 1.0))

    @cached_property
    def photo_stats(self) -> dict[int, Appearance]:
        """Each observed part's statistics in the photo (parts too small for statistics absent); with a
        backbone, its deep texture statistics too (the photo is read once per scene)."""
        maps = None if self.features is None else self.features(lt.exposed_srgb(self.photo_linear, 1.0))
        return {i: with_deep(a, maps, mask) for i, mask in self.masks.items()
                if (a := appearance(self.photo_lab, mask)) is not None}


def with_deep(stats: Appearance, maps: Sequence[np.ndarray] | None, mask: np.ndarray) -> Appearance:
    """`stats` with the region's deep texture statistics from a frame's feature maps (unchanged without)."""
    return stats if maps is None else replace(stats, deep=deep_stats(maps, mask))


def part_regions(ids: np.ndarray, indices: Sequence[int], erode_pixels: int = 1) -> dict[int, Region]:
    """Part index -> its region in a frame's part map, eroded (what every render of the frame is read in)."""
    return {i: Region.of(erode(ids == i, erode_pixels)) for i in indices}


def region_terms(lab: np.ndarray, regions: Mapping[int, Region], photo: Mapping[int, Appearance],
                 indices: Sequence[int], maps: Sequence[np.ndarray] | None = None) -> dict[int, np.ndarray | None]:
    """Per part: the distance terms of its rendered region to its photo region (None when either is missing).

    `regions`: the frame's `part_regions`; `maps`: the render's backbone feature maps
    (`FitScene.deep_maps`), for the deep term.
    """
    out: dict[int, np.ndarray | None] = {}
    for index in indices:
        region = regions[index]
        rendered = appearance(lab, region)
        out[index] = (None if rendered is None or index not in photo
                      else terms(with_deep(rendered, maps, region.mask), photo[index]))
    return out


def region_distances(lab: np.ndarray, regions: Mapping[int, Region], photo: Mapping[int, Appearance],
                     indices: Sequence[int], weights: Weights) -> dict[int, float | None]:
    """Per part: distance of its rendered region to its photo region (None when either is missing)."""
    return {i: None if t is None else weigh(t, weights) for i, t in region_terms(lab, regions, photo, indices).items()}


def score_lighting(frame: FrameRenderer, scene: FitScene, materials: Sequence[Any],
                   hypotheses: Sequence[tuple[lt.Hypothesis, Any]], weights: Weights,
                   erode_pixels: int = 1) -> list[tuple[lt.Hypothesis, float, float]]:
    """(hypothesis, exposure, loss) of each (hypothesis, envmap spec): how well it explains the photo.

    Each hypothesis is rendered once with `materials` (one spec per mesh part); its exposure is the
    closed-form fit of the per-part mean colours; its loss is the pixel-weighted mean part distance
    (`region_distances`). Albedo-blind shading losses and lobe reshaping of the envmap were measured
    and did not pay (docs/decisions.md D49, D50).
    """
    if not scene.photo_stats:
        raise ValueError("no observed part to light (every aligned part is too small)")
    ids = frame.part_ids(scene.mesh, scene.camera)
    photo = scene.photo_stats
    photo_means = lt.region_means(scene.photo_linear, scene.masks)
    regions = part_regions(ids, sorted(scene.masks), erode_pixels)
    rendered_masks = {i: region.mask for i, region in regions.items()}
    scored = []
    for hypothesis, envmap in hypotheses:
        rgba = scene.render(frame, materials, envmap)
        scale = lt.exposure(lt.region_means(rgba[..., :3], rendered_masks), photo_means)
        dists = region_distances(scene.exposed_lab(rgba, scale), regions, photo, sorted(scene.masks), weights)
        sizes = {i: float(scene.masks[i].sum()) for i, d in dists.items() if d is not None}
        loss = sum(sizes[i] * float(dists[i] or 0.0) for i in sizes) / sum(sizes.values()) if sizes else math.inf
        scored.append((hypothesis, scale, loss))
    return scored


def estimate_lighting(frame: FrameRenderer, scene: FitScene, materials: Sequence[Any],
                      envmaps: Mapping[int, Callable[[float], Any]], rotations: int, weights: Weights,
                      keep: int | None = None, erode_pixels: int = 1) -> tuple[lt.Hypothesis, float, float, int]:
    """(hypothesis, exposure, loss, renders) of the envmap and rotation that best explain the photo.

    `envmaps`: envmap id -> its render spec at a rotation. Every envmap is tried at `rotations`
    azimuths; with more envmaps than `keep`, all are first screened at (up to) two azimuths and only
    the `keep` best are searched at every azimuth, so the cost grows with the library by two renders
    per envmap rather than `rotations`.
    """
    angles = lt.rotations(rotations)
    scored: dict[lt.Hypothesis, tuple[lt.Hypothesis, float, float]] = {}

    def run(hypotheses: list[lt.Hypothesis]) -> None:
        fresh = [h for h in hypotheses if h not in scored]
        for item in score_lighting(frame, scene, materials, [(h, envmaps[h.envmap_id](h.rotation)) for h in fresh],
                                   weights, erode_pixels):
            scored[item[0]] = item

    ids = sorted(envmaps)
    if keep is not None and 0 < keep < len(ids):
        run([lt.Hypothesis(e, r) for e in ids for r in angles[:: max(1, len(angles) // 2)][:2]])

        def screened(envmap_id: int) -> float:
            losses = [loss for h, _, loss in scored.values() if h.envmap_id == envmap_id and math.isfinite(loss)]
            return min(losses, default=math.inf)

        ids = sorted(ids, key=lambda e: (screened(e), e))[:keep]
    run([lt.Hypothesis(e, r) for e in ids for r in angles])
    h, scale, value = lt.best(list(scored.values()))
    return h, scale, value, len(scored)


@dataclass
class CandidateRenders:
    """The slot renders of one pair: which render shows each (part, candidate)."""

    renders: list[np.ndarray]  # (size, size, 4) un-premultiplied linear RGB and coverage (`FitScene.render`)
    where: dict[int, dict[int, int]]  # part index -> candidate material -> index into `renders`
    ids: np.ndarray  # the frame's part indices


def render_candidates(frame: FrameRenderer, scene: FitScene, base: Mapping[int, int | None],
                      candidates: Mapping[int, Sequence[Candidate]], spec_of: Callable[[int | None], Any],
                      envmap: Any) -> CandidateRenders:
    """One render per candidate slot (`render_slots`) under `envmap`.

    `base`: the material of every mesh part that is not switched (part index -> material id, None or
    absent: built-in); `spec_of` turns a material id into a render spec.
    """
    out = CandidateRenders([], {i: {} for i in candidates}, frame.part_ids(scene.mesh, scene.camera))
    for slot in render_slots(candidates):
        rgba = scene.render(frame, [spec_of(slot.get(p.index, base.get(p.index))) for p in scene.mesh.parts], envmap)
        out.renders.append(rgba)
        for index, material in slot.items():
            if material not in out.where[index]:
                out.where[index][material] = len(out.renders) - 1
    return out


def candidate_terms(renders: CandidateRenders, scene: FitScene, exposure: float, erode_pixels: int = 1,
                    maps: Sequence[Sequence[np.ndarray] | None] | None = None,
                    regions: Mapping[int, Region] | None = None) -> dict[int, dict[int, np.ndarray | None]]:
    """Part index -> {candidate material: its distance terms to the photo} with the renders at `exposure`.

    `maps`: each render's backbone feature maps (`FitScene.deep_maps`), for the deep term; `regions`:
    the frame's `part_regions` when the caller measures the same renders again (other exposures).
    """
    photo = scene.photo_stats
    regions = regions if regions is not None else part_regions(renders.ids, sorted(renders.where), erode_pixels)
    out: dict[int, dict[int, np.ndarray | None]] = {i: {} for i in renders.where}
    for k, rgba in enumerate(renders.renders):
        shown = {i: mid for i, by in renders.where.items() for mid, at in by.items() if at == k}
        if not shown:
            continue
        lab = scene.exposed_lab(rgba, exposure)
        for index, value in region_terms(lab, regions, photo, sorted(shown),
                                         None if maps is None else maps[k]).items():
            out[index][shown[index]] = value
    return out


def weighed(measured: Mapping[int, Mapping[int, np.ndarray | None]],
            weights: Weights) -> dict[int, dict[int, float | None]]:
    """Part index -> {candidate material: distance}: `candidate_terms` under `weights`."""
    return {i: {mid: None if t is None else weigh(t, weights) for mid, t in by.items()} for i, by in measured.items()}


EXPOSURE_STEP = 0.25  # stops between the exposures `select_profiled` tries


def exposure_grid(stops: float) -> tuple[float, ...]:
    """Factors of an exposure `stops` either side of it in `EXPOSURE_STEP`s (just 1.0 for 0 stops)."""
    n = int(round(max(0.0, stops) / EXPOSURE_STEP))
    return tuple(float(2.0 ** (k * EXPOSURE_STEP)) for k in range(-n, n + 1))


def profiled_terms(renders: CandidateRenders, scene: FitScene, candidates: Mapping[int, Sequence[Candidate]],
                   exposure: float, weights: Weights, prior_weight: float,
                   grid: Sequence[float | np.ndarray] = (1.0,),
                   erode_pixels: int = 1) -> tuple[dict[int, dict[int, np.ndarray | None]], dict[int, dict[int, float]],
                                                   float]:
    """(part -> {candidate: its distance terms}, part -> {candidate: the exposure they are measured at},
    the winners' exposure).

    A material's albedo and the photo's exposure trade off (a dark material brightly exposed looks
    like a light one). So each candidate is measured at the exposure (a factor of `exposure` on
    `grid`) that best explains the whole photo if its part takes that candidate: its own cost plus
    every other part's cheapest candidate at that exposure. A light material is then not judged at
    the exposure a dark wrong winner asked for; with a single observed part every candidate gets
    its own exposure (lightness and exposure cannot be told apart there). The winners' exposure is
    the grid point where the sum of every part's cheapest cost is lowest. No new renders: each
    grid point re-exposes the same candidate renders (docs/decisions.md D42). A grid point may be
    per-channel factors (an exposure and a white balance; measured in experiments/fit_oracle and not
    used by the stage, D43), and its exposures are then those factors. The deep texture term is
    read once per render, at the lighting's exposure, for every grid point: a backbone read per
    render and exposure would cost a forward pass each for a term that a quarter stop barely moves.
    """
    trials = [exposure * (float(f) if np.ndim(f) == 0 else np.asarray(f, np.float64)) for f in grid]
    maps = None if scene.features is None else [scene.deep_maps(rgba, exposure) for rgba in renders.renders]
    regions = part_regions(renders.ids, sorted(renders.where), erode_pixels)
    measured = [candidate_terms(renders, scene, e, erode_pixels, maps, regions) for e in trials]
    parts = [i for i in candidates if candidates[i]]
    costs: list[dict[int, dict[int, float]]] = []
    for terms_at in measured:
        dists = weighed(terms_at, weights)
        costs.append({i: {s.candidate.material_id: s.cost
                              for s in rank_candidates(candidates[i], dists[i], prior_weight)} for i in parts})
    best = [{i: min(c[i].values()) for i in parts} for c in costs]
    total = [sum(b.values()) for b in best]
    chosen = {i: {c.material_id: min(range(len(trials)), key=lambda k: costs[k][i][c.material_id] + total[k]
                                     - best[k][i]) for c in candidates[i]} for i in parts}
    terms = {i: {mid: measured[k][i].get(mid) for mid, k in by.items()} for i, by in chosen.items()}
    exposures = {i: {mid: trials[k] for mid, k in by.items()} for i, by in chosen.items()}
    return terms, exposures, trials[min(range(len(trials)), key=lambda k: total[k])]


def select_profiled(renders: CandidateRenders, scene: FitScene, candidates: Mapping[int, Sequence[Candidate]],
                    exposure: float, weights: Weights, prior_weight: float, stops: float,
                    erode_pixels: int = 1) -> tuple[dict[int, dict[int, float | None]], dict[int, dict[int, float]],
                                                    float]:
    """(distances, each candidate's exposure, the winners' exposure) of `profiled_terms`, searched `stops`
    either side of the lighting's `exposure`."""
    terms, exposures, joint = profiled_terms(renders, scene, candidates, exposure, weights, prior_weight,
                                             exposure_grid(stops), erode_pixels)
    return weighed(terms, weights), exposures, joint
