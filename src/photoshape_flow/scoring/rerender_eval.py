"""Re-render error: a pair's PhotoShape rendered at the exemplar's camera against the photo.

Every method is rendered under the same studio envmap, so the error compares materials, not lights.
A part's refinement (`fit.refine`: tint, roughness scale, UV transform) is applied only when the
caller passes it, so the evaluation can report a method both as selected and as refined.
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import crop_square, exemplar_at, square_box, zoom_to_fit
from photoshape_flow.db import models as m
from photoshape_flow.evaluation.tables import REFINED
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.pipeline.render_inputs import material_spec
from photoshape_flow.publish.photoshapes import choose_envmap
from photoshape_flow.render import Camera, EnvmapSpec
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.specs import Refinement
from photoshape_flow.store import BlobStore

log = logging.getLogger(__name__)

Refinements = Mapping[int, Mapping[str, Any]]  # part index -> the rank-1 row's stored refinement


class MaterialSpecs:
    """Library materials' render specs, loaded once, with a part's refinement applied on request."""

    def __init__(self, store: BlobStore):
        self.store = store
        self._specs: dict[int, Any] = {}

    def get(self, session: Session, material_id: int, refinement: Mapping[str, Any] | None = None) -> Any:
        if material_id not in self._specs:
            self._specs[material_id] = material_spec(session.get(m.Material, material_id), self.store)
        spec = self._specs[material_id]
        if spec is None or not refinement:
            return spec

        return replace(spec, refinement=Refinement.from_dict(refinement))

    def for_parts(self, session: Session, parts: Any, materials: Mapping[int, int | None],
                  refinements: Refinements | None = None) -> list[Any]:
        """One spec per mesh part, in mesh order (None: the part's built-in material)."""
        refinements = refinements or {}
        return [self.get(session, mid, refinements.get(p.index)) if (mid := materials.get(p.index)) else None
                for p in parts]


class ShapeMeshes:
    """Shapes' meshes, read from the store once per evaluation."""

    def __init__(self, store: BlobStore):
        self.store = store
        self._meshes: dict[int, Any] = {}

    def get(self, session: Session, shape_id: int) -> Any:
        if shape_id not in self._meshes:
            self._meshes[shape_id] = ShapeMesh.from_npz_bytes(
                self.store.read_bytes(session.get(m.Shape, shape_id).mesh_blob))
        return self._meshes[shape_id]


class Rerenderer:
    """Renders a pair's PhotoShape at the exemplar's camera, cropped like the exemplar."""

    def __init__(self, store: BlobStore, size: int, spp: int):
        self.store = store
        self.size = size
        self.spp = spp
        self.renderer = default_renderer(store)
        self.specs = MaterialSpecs(store)
        self.meshes = ShapeMeshes(store)
        self.envmap = None

    def set_envmap(self, envmap: m.Envmap | None) -> None:
        if envmap is not None and envmap.blob:
            self.envmap = EnvmapSpec(self.store.resolve(envmap.blob))

    def render(self, session: Session, pair: m.Pair, materials: Mapping[int, int | None],
               refinements: Refinements | None = None) -> tuple[np.ndarray, np.ndarray]:
        mesh = self.meshes.get(session, pair.shape_id)
        specs = self.specs.for_parts(session, mesh.parts, materials, refinements)
        camera = zoom_to_fit(mesh, Camera(pair.azimuth, pair.elevation, pair.camera_distance, pair.fov))
        render_size = int(math.ceil(self.size * 1.25))
        result = self.renderer.beauty(mesh, specs, camera, self.envmap, size=render_size, spp=self.spp, seed=0)
        box = square_box(result.alpha > 0.5)
        if box is None:
            raise ValueError("the shape is not visible at the pair's camera")
        rgb = crop_square(result.srgb, *box, fill=255)
        alpha = crop_square(result.alpha, *box, fill=0.0)
        rgb = cv2.resize(rgb, (self.size, self.size), interpolation=cv2.INTER_AREA)
        alpha = cv2.resize(alpha, (self.size, self.size), interpolation=cv2.INTER_AREA) > 0.5
        return rgb, alpha


def rerender_error(render: np.ndarray, exemplar: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """RMSE (sRGB in [0, 1]) and mean SSIM (grey) inside the exemplar's mask."""
    from skimage.metrics import structural_similarity

    a = render.astype(np.float64) / 255.0
    b = exemplar.astype(np.float64) / 255.0
    if not mask.any():
        return float("nan"), float("nan")
    rmse = float(np.sqrt(((a - b) ** 2)[mask].mean()))
    grey_a = cv2.cvtColor(render, cv2.COLOR_RGB2GRAY).astype(np.float64) / 255.0
    grey_b = cv2.cvtColor(exemplar, cv2.COLOR_RGB2GRAY).astype(np.float64) / 255.0
    _, ssim_map = structural_similarity(grey_a, grey_b, data_range=1.0, full=True, win_size=7)
    return rmse, float(ssim_map[mask].mean())


def rendered_variants(render: Callable[[dict[int, Any] | None], Any], refined: dict[int, Any],
                      method_refines: bool) -> dict[str, Any]:
    """A pair's rendered figure as selected ("") and, for a method that refines, as refined (`REFINED`):
    rendered again only when this pair has refinements, else the selected value again, so both
    figures cover the same pairs."""
    plain = render(None)
    if not method_refines:
        return {"": plain}
    return {"": plain, REFINED: render(refined) if refined else plain}


class RerenderScores:
    """The re-render error of at most `max_pairs` pairs per method, under the PhotoShapes' studio envmap."""

    def __init__(self, store: BlobStore, size: int, spp: int, max_pairs: int | None):
        self.store, self.size, self.spp, self.max_pairs = store, size, spp, max_pairs
        self.rerenderer: Any = None
        self.pairs: dict[str, int] = defaultdict(int)

    def wants(self, method_key: str) -> bool:
        return self.max_pairs is None or self.pairs[method_key] < self.max_pairs

    def error(self, session: Session, pair: m.Pair, exemplar: m.Exemplar, method_key: str,
              chosen: dict[int, int | None], refinements: dict[int, Any] | None) -> tuple[float, float] | None:
        if self.rerenderer is None:
            self.rerenderer = Rerenderer(self.store, self.size, self.spp)
            self.rerenderer.set_envmap(choose_envmap(session))
        try:
            render, _ = self.rerenderer.render(session, pair, chosen, refinements)
            photo, fg = exemplar_at(self.store.load_image(exemplar.image_blob),
                                    self.store.load_image(exemplar.mask_blob), self.size)
            errors = rerender_error(render, photo, fg)
        except Exception as exc:  # one unrenderable pair never stops the evaluation
            log.warning("pair %s: re-render failed: %s", pair.id, exc)
            return None
        self.pairs[method_key] += not refinements  # the refined render of a counted pair is not another pair
        return errors
