"""What a fit run reads once and per pair: the run's context (classifier, materials, envmaps, renderer,
fitted weights) and a pair's scene at the fit resolution with the classifier ranking it starts from.

Kept apart from the stage's loop (`fitting.fit`) because the calibration (`fitting.calibration`)
and the experiments build the same context and pair data around validation renders.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import exemplar_at, resize_labels
from photoshape_flow.classify.feature_maps import FeatureMaps
from photoshape_flow.db import models as m
from photoshape_flow.fit.appearance import Weights
from photoshape_flow.fit.scene import FitScene, FrameRenderer
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.hashing import stable_hash
from photoshape_flow.method_keys import FIT, MethodKey
from photoshape_flow.networks.calibrations import material_lab
from photoshape_flow.pipeline.render_inputs import material_spec
from photoshape_flow.profiles import FitConfig
from photoshape_flow.recognition.inference import ALIGNMENT_METHOD
from photoshape_flow.render import Camera, EnvmapSpec
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_OK

METHOD = FIT
CODE_VERSION = "fit-9"  # fit-2: fitted weights and temperature (D34); fit-3: the highlight term (D38);
#                         fit-4: renders blended with the photo's background at the silhouette (D41);
#                         fit-5: each candidate judged at its own best exposure (D42);
#                         fit-6: weights calibrated on photos degraded at the exemplars' size (D45);
#                         fit-7: rows carry the calibrated score as their posterior (the gallery's confidence);
#                         fit-8: the deep texture term (D54); fit-9: the refinement's tint solved like for like (D67)


def weights_of(cfg: FitConfig) -> Weights:
    """The profile's hand-set distance weights (the fallback when no fitted ones are stored)."""
    return Weights(cfg.color_weight, cfg.contrast_weight, cfg.gradient_weight, cfg.highlight_weight, cfg.deep_weight)


# -- what one pair is made of ----------------------------------------------------------------------------
@dataclass
class PairData:
    """A pair's scene at the fit resolution and the classifier ranking it starts from."""

    pair: m.Pair
    scene: FitScene
    rows: dict[int, list[m.Assignment]]  # part index -> the classifier's rows, best first
    source_hash: str | None  # params_hash of those rows

    def rank1(self) -> dict[int, int | None]:
        """Part index -> the classifier's first material."""
        return {index: rows[0].material_id for index, rows in self.rows.items() if rows}


class FitContext:
    """What one fit run needs once: the classifier, materials, their colours and specs, envmaps, a renderer."""

    def __init__(self, session: Session, store: BlobStore, classifier: m.Classifier, cfg: FitConfig,
                 renderer: RendererProtocol | None = None):
        self.store = store
        self.cfg = cfg
        self.classifier = classifier
        self.source_key = str(MethodKey.for_classifier(classifier.id))
        self.method_key = str(MethodKey.fit_of(classifier.id))
        mats = session.execute(
            sa.select(m.Material).where(m.Material.enabled, m.Material.status == STATUS_OK).order_by(m.Material.id)
        ).scalars().all()
        self.material_rows = {mat.id: mat for mat in mats}
        self.material_substance = {mat.id: mat.substance for mat in mats}
        self.material_labs = {mat.id: lab for mat in mats if (lab := material_lab(mat, store)) is not None}
        self.untrained = sorted(set(self.material_substance) - {int(x) for x in (classifier.materials or [])})
        envmaps = session.execute(
            sa.select(m.Envmap).where(m.Envmap.enabled, m.Envmap.status == STATUS_OK, m.Envmap.blob.is_not(None))
            .order_by(m.Envmap.id)
        ).scalars().all()
        training = [e for e in envmaps if (e.split or "train") == "train"] or list(envmaps)
        self.envmaps = {e.id: e.blob for e in training}
        self._renderer = renderer
        # fitted weights and temperature (`fitting.calibration`, D34); None: the profile's hand-set ones
        self.calibration: dict[str, Any] | None = None
        self._frame: FrameRenderer | None = None
        self._features: FeatureMaps | None = None
        self._specs: dict[int, Any] = {}
        self._meshes: dict[int, Any] = {}

    @property
    def frame(self) -> FrameRenderer:
        if self._frame is None:
            if self._renderer is None:
                self._renderer = default_renderer(self.store)
            self._frame = FrameRenderer(self._renderer, self.cfg.size, self.cfg.spp)
        return self._frame

    @property
    def features(self) -> Callable[[np.ndarray], list[np.ndarray]] | None:
        """The backbone that reads frames for the deep texture term, built once (None when the profile's
        `texture_backbone` is "none")."""
        if self.cfg.texture_backbone == "none":
            return None
        if self._features is None:
            self._features = FeatureMaps(self.cfg.texture_backbone)
        return self._features.maps

    def spec(self, material_id: int | None) -> Any:
        """The render spec of a material (None: the part's built-in material)."""
        if material_id is None or material_id not in self.material_rows:
            return None
        if material_id not in self._specs:
            self._specs[material_id] = material_spec(self.material_rows[material_id], self.store)
        return self._specs[material_id]

    def envmap_spec(self, envmap_id: int | None, rotation: float = 0.0) -> Any:
        """The render spec of a training envmap at a rotation (None: unknown id, the constant white sky)."""
        blob = self.envmaps.get(envmap_id) if envmap_id is not None else None
        return None if blob is None else EnvmapSpec(self.store.resolve(blob), rotation=rotation)

    def light_envmap(self, light: dict[str, Any]) -> Any:
        """The render spec of an exemplar's stored lighting (`fitting.steps.lighting_estimate`): its training
        envmap at its rotation."""
        return self.envmap_spec(light.get("envmap_id"), float(light.get("rotation", 0.0)))

    def mesh(self, shape: m.Shape) -> Any:
        if shape.id not in self._meshes:
            if not shape.mesh_blob:
                raise ValueError(f"shape {shape.id} has no mesh")
            self._meshes = {shape.id: ShapeMesh.from_npz_bytes(self.store.read_bytes(shape.mesh_blob))}
        return self._meshes[shape.id]

    @property
    def weights(self) -> Weights:
        """The distance weights in use: the fitted ones when calibrated, else the profile's."""
        if self.calibration is None:
            return weights_of(self.cfg)
        w = self.calibration["weights"]
        return Weights(float(w["color"]), float(w["contrast"]), float(w["gradient"]), float(w["highlight"]),
                       float(w.get("deep", 0.0)))

    @property
    def prior_weight(self) -> float:
        return self.cfg.prior_weight if self.calibration is None else float(self.calibration["weights"]["prior"])

    @property
    def temperature(self) -> float:
        """The softmax temperature of the rows' scores (1 with the hand-set weights: uncalibrated)."""
        return 1.0 if self.calibration is None else float(self.calibration["temperature"])

    @property
    def params(self) -> dict[str, Any]:
        weights = None if self.calibration is None else stable_hash(
            {k: self.calibration.get(k) for k in ("weights", "temperature", "blur")})
        return {"code": CODE_VERSION, "config": dataclasses.asdict(self.cfg), "source": self.source_key,
                "fitted_weights": weights}

    def lighting_key(self, reference_pair: int, reference_hash: str | None) -> str:
        """What a stored lighting estimate depends on: its pair and ranking, the envmaps, the config."""
        return stable_hash({**self.params, "pair": reference_pair, "ranking": reference_hash,
                            "envmaps": sorted(self.envmaps.items())})


def weights_report(ctx: FitContext) -> dict[str, Any]:
    """What a run says about its cost: fitted (with the held-out figures) or the profile's hand-set fallback."""
    w = ctx.weights
    out: dict[str, Any] = {"source": "hand-set" if ctx.calibration is None else "fitted",
                           "color": round(w.color, 4), "contrast": round(w.contrast, 4),
                           "gradient": round(w.gradient, 4), "highlight": round(w.highlight, 4),
                           "deep": round(w.deep, 4),
                           "prior": round(ctx.prior_weight, 4),
                           "temperature": round(ctx.temperature, 4), "blur": ctx.cfg.blur}
    if ctx.calibration is not None:
        out["model"] = ctx.calibration.get("model", "fitted")
        out["cases"] = ctx.calibration.get("cases")
        out["held_out"] = ctx.calibration.get("held_out")
    return out


def load_pair(session: Session, ctx: FitContext, pair: m.Pair) -> PairData:
    """A pair's photo, aligned regions and classifier rows at the fit resolution; a one-line error when incomplete."""
    shape, exemplar = session.get(m.Shape, pair.shape_id), session.get(m.Exemplar, pair.exemplar_id)
    if shape is None or exemplar is None or not exemplar.image_blob:
        raise ValueError(f"pair {pair.id}: shape or exemplar image missing")
    alignment = session.execute(
        sa.select(m.Alignment).where(m.Alignment.pair_id == pair.id, m.Alignment.method == ALIGNMENT_METHOD,
                                     m.Alignment.status == STATUS_OK)
    ).scalar_one_or_none()
    blob = alignment and (alignment.crf_blob or alignment.flow_blob or alignment.coarse_blob)
    if not blob:
        raise ValueError(f"pair {pair.id}: no fine alignment")
    size = ctx.cfg.size
    image = ctx.store.load_image(exemplar.image_blob)
    mask = ctx.store.load_image(exemplar.mask_blob) if exemplar.mask_blob else np.full(image.shape[:2], 255, np.uint8)
    rgb, foreground = exemplar_at(image, mask, size)
    labels = ctx.store.load_image(blob)
    labels = resize_labels(labels[..., 0] if labels.ndim == 3 else labels, size).astype(np.int32)
    by_part = dict(session.execute(sa.select(m.Part.id, m.Part.index).where(m.Part.shape_id == shape.id)).all())
    rows: dict[int, list[m.Assignment]] = {}
    source_hash = None
    for row in session.execute(
        sa.select(m.Assignment).where(m.Assignment.pair_id == pair.id, m.Assignment.method_key == ctx.source_key)
        .order_by(m.Assignment.part_id, m.Assignment.rank)
    ).scalars():
        rows.setdefault(by_part[row.part_id], []).append(row)
        source_hash = row.params_hash
    observed = [index for index, part_rows in rows.items() if not part_rows[0].unobserved]
    camera = Camera(float(pair.azimuth), float(pair.elevation), float(pair.camera_distance), float(pair.fov))
    scene = FitScene.from_photo(ctx.mesh(shape), camera, rgb, labels, observed, ctx.cfg.erode, blur=ctx.cfg.blur,
                                foreground=foreground, features=ctx.features)
    return PairData(pair, scene, rows, source_hash)


def reference_pair(session: Session, ctx: FitContext, exemplar_id: int) -> m.Pair | None:
    """The exemplar's pair whose rank-1 assignment lights it: best shape match with a ranking and an alignment."""
    return session.execute(
        sa.select(m.Pair)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Alignment, sa.and_(m.Alignment.pair_id == m.Pair.id, m.Alignment.method == ALIGNMENT_METHOD,
                                   m.Alignment.status == STATUS_OK))
        .where(m.Pair.exemplar_id == exemplar_id, ~m.Pair.exclude, ~m.Shape.exclude,
               m.Pair.id.in_(sa.select(m.Assignment.pair_id).where(m.Assignment.method_key == ctx.source_key)))
        .order_by(sa.func.coalesce(m.Pair.exemplar_rank, 1 << 30), m.Pair.distance, m.Pair.id)
        .limit(1)
    ).scalar_one_or_none()
