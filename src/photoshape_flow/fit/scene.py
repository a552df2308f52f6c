"""A pair as the fit sees it (photo, aligned regions, shape, camera) and the renders that score it; no database.

`FrameRenderer` renders a shape at a pair's camera in the exemplar's frame (the tight square crop of
the silhouette, as fine alignment frames the part map). `estimate_lighting` and `measure_candidates`
are the two render loops of the fit stage; they take render specs and return numbers, so tests run
them on generated scenes and `pipeline.fit` on the database's pairs.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from photoshape_flow.align.partmap import resize_labels, zoom_to_fit
from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit.appearance import Appearance, Weights, appearance, distance, erode, to_lab
from photoshape_flow.fit.candidates import Candidate
from photoshape_flow.fit.select import render_slots
from photoshape_flow.imaging.squares import crop_square, square_box

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

    def render(self, mesh: Any, materials: Sequence[Any], camera: Any, envmap: Any) -> np.ndarray:
        """(size, size, 3) linear radiance in the frame (background 0)."""
        zoomed, box, _ = self._frame(mesh, camera)
        result = self.renderer.beauty(mesh, list(materials), zoomed, envmap, size=self.render_size, spp=self.spp,
                                      background="transparent", seed=0)
        crop = crop_square(result.hdr, *box, fill=0.0)
        return cv2.resize(crop, (self.size, self.size), interpolation=cv2.INTER_AREA)


@dataclass
class FitScene:
    """What a render is compared with: the photo at the frame's size and each observed part's region in it."""

    mesh: Any
    camera: Any
    photo_linear: np.ndarray  # (size, size, 3)
    photo_lab: np.ndarray
    masks: dict[int, np.ndarray]  # observed part index -> region of the photo (eroded)

    @classmethod
    def from_photo(cls, mesh: Any, camera: Any, photo_srgb: np.ndarray, labels: np.ndarray,
                   indices: Sequence[int], erode_pixels: int = 1, min_pixels: int = 12) -> FitScene:
        """`photo_srgb` uint8 and `labels` (part index per pixel) at the same size; parts below `min_pixels` dropped."""
        masks = {}
        for index in indices:
            region = erode(labels == index, erode_pixels)
            if int(region.sum()) >= min_pixels:
                masks[index] = region
        return cls(mesh, camera, lt.photo_linear(photo_srgb), to_lab(photo_srgb), masks)

    def photo_stats(self) -> dict[int, Appearance]:
        return {i: a for i, mask in self.masks.items() if (a := appearance(self.photo_lab, mask)) is not None}


def region_distances(lab: np.ndarray, ids: np.ndarray, photo: Mapping[int, Appearance], indices: Sequence[int],
                     weights: Weights, erode_pixels: int = 1) -> dict[int, float | None]:
    """Per part: distance of its rendered region to its photo region (None when either is missing)."""
    out: dict[int, float | None] = {}
    for index in indices:
        rendered = appearance(lab, erode(ids == index, erode_pixels))
        out[index] = None if rendered is None or index not in photo else distance(rendered, photo[index], weights)
    return out


def estimate_lighting(frame: FrameRenderer, scene: FitScene, materials: Sequence[Any],
                      hypotheses: Sequence[tuple[lt.Hypothesis, Any]], weights: Weights,
                      erode_pixels: int = 1) -> tuple[lt.Hypothesis, float, float]:
    """(hypothesis, exposure, loss) of the (envmap spec) hypothesis that best explains the photo.

    Each hypothesis is rendered once with `materials` (one spec per mesh part); its exposure is the
    closed-form fit of the per-part mean colours; its loss the pixel-weighted mean part distance.
    """
    ids = frame.part_ids(scene.mesh, scene.camera)
    photo = scene.photo_stats()
    photo_means = lt.region_means(scene.photo_linear, scene.masks)
    rendered_masks = {i: erode(ids == i, erode_pixels) for i in scene.masks}
    scored = []
    for hypothesis, envmap in hypotheses:
        linear = frame.render(scene.mesh, materials, scene.camera, envmap)
        scale = lt.exposure(lt.region_means(linear, rendered_masks), photo_means)
        dists = region_distances(to_lab(lt.exposed_srgb(linear, scale)), ids, photo, sorted(scene.masks), weights,
                                 erode_pixels)
        sizes = {i: float(scene.masks[i].sum()) for i, d in dists.items() if d is not None}
        loss = sum(sizes[i] * float(dists[i] or 0.0) for i in sizes) / sum(sizes.values()) if sizes else math.inf
        scored.append((hypothesis, scale, loss))
    return lt.best(scored)


def measure_candidates(frame: FrameRenderer, scene: FitScene, base: Mapping[int, int | None],
                       candidates: Mapping[int, Sequence[Candidate]], spec_of: Callable[[int | None], Any],
                       envmap: Any, exposure: float, weights: Weights,
                       erode_pixels: int = 1) -> dict[int, dict[int, float | None]]:
    """Part index -> {candidate material: distance}, one render per candidate slot (`render_slots`).

    `base`: the material of every mesh part that is not switched (part index -> material id, None or
    absent: built-in); `spec_of` turns a material id into a render spec.
    """
    ids = frame.part_ids(scene.mesh, scene.camera)
    photo = scene.photo_stats()
    measured: dict[int, dict[int, float | None]] = {i: {} for i in candidates}
    for slot in render_slots(candidates):
        materials = [spec_of(slot.get(p.index, base.get(p.index))) for p in scene.mesh.parts]
        linear = frame.render(scene.mesh, materials, scene.camera, envmap)
        lab = to_lab(lt.exposed_srgb(linear, exposure))
        fresh = [i for i, mid in slot.items() if mid not in measured[i]]
        for index, value in region_distances(lab, ids, photo, fresh, weights, erode_pixels).items():
            measured[index][slot[index]] = value
    return measured
