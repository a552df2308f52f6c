"""Relighting error: does the PhotoShape look right under light and from views the photo never showed?

The re-render error at the exemplar's camera rewards a method for matching that one photo (and `fit`
minimises exactly that), so it cannot tell a right material from one that only looks right there. The
relighting error renders the *true* shape twice, with a method's rank-1 materials and with the ground
truth's, under a held-out envmap (one the pipeline did not train with, where the collection has one)
from three novel views (the pair's camera turned by 90, 180 and 270 degrees), and takes the RMSE of
the two inside the silhouette. Only pairs whose shape is the exemplar's own count, and only when every
part's true material is in the library (otherwise there is no "true" render to compare with).
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import zoom_to_fit
from photoshape_flow.db import models as m
from photoshape_flow.evaluation.groundtruth import TruthEntry
from photoshape_flow.publish.photoshapes import choose_envmap
from photoshape_flow.render import Camera, EnvmapSpec
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.scoring.rerender_eval import MaterialSpecs, Refinements, ShapeMeshes
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_OK

log = logging.getLogger(__name__)

NOVEL_VIEWS_DEG = (90.0, 180.0, 270.0)  # azimuth turns from the pair's camera


def silhouette_rmse(a: np.ndarray, b: np.ndarray, alpha: np.ndarray) -> float:
    """RMSE of two sRGB renders (uint8) over the pixels of `alpha` (NaN when empty)."""
    mask = np.asarray(alpha, bool)
    if not mask.any():
        return float("nan")
    diff = a.astype(np.float64) / 255.0 - b.astype(np.float64) / 255.0
    return float(np.sqrt((diff ** 2)[mask].mean()))


def held_out_envmap(session: Session) -> m.Envmap | None:
    """The first enabled envmap not in the training split; else the PhotoShapes' studio envmap."""
    rows = session.execute(
        sa.select(m.Envmap).where(m.Envmap.enabled, m.Envmap.status == STATUS_OK, m.Envmap.blob.is_not(None))
        .order_by(m.Envmap.id)
    ).scalars().all()
    held = [e for e in rows if (e.split or "train") != "train"]
    if held:
        return held[0]

    return choose_envmap(session)


def true_materials(session: Session, shape: m.Shape, truth: TruthEntry) -> dict[int, int] | None:
    """Part index -> the id of the library material the truth names for it; None when a part has no
    truth or its material is not ingested (no true render can be made)."""
    names = {name: p.material for name, p in truth.parts.items()}
    wanted = {part.index: names.get(part.name or "") for part in shape.parts}
    if not wanted or any(v is None for v in wanted.values()):
        return None
    ids = dict(session.execute(sa.select(m.Material.name, m.Material.id)
                               .where(m.Material.name.in_(set(wanted.values())))).all())
    if any(name not in ids for name in wanted.values()):
        return None
    return {index: ids[name] for index, name in wanted.items()}


class Relighter:
    """Renders a shape with given materials under one envmap from the three novel views of a pair."""

    def __init__(self, session: Session, store: BlobStore, size: int, spp: int):
        self.store = store
        self.size = size
        self.spp = spp
        self.renderer = default_renderer(store)
        row = held_out_envmap(session)
        self.envmap_name = row.name if row is not None else None
        self.envmap = EnvmapSpec(store.resolve(row.blob)) if row is not None else None
        self.meshes = ShapeMeshes(store)
        self.specs = MaterialSpecs(store)

    def views(self, session: Session, pair: m.Pair, materials: Mapping[int, int | None],
              refinements: Refinements | None = None) -> list[tuple[Any, Any]]:
        """(sRGB uint8, alpha mask) of each novel view."""
        mesh = self.meshes.get(session, pair.shape_id)
        specs = self.specs.for_parts(session, mesh.parts, materials, refinements)
        out = []
        for turn in NOVEL_VIEWS_DEG:
            camera = zoom_to_fit(mesh, Camera(pair.azimuth + math.radians(turn), pair.elevation,
                                              pair.camera_distance, pair.fov))
            result = self.renderer.beauty(mesh, specs, camera, self.envmap, size=self.size, spp=self.spp, seed=0)
            out.append((result.srgb, result.alpha > 0.5))
        return out


def relighting_error(relighter: Relighter, session: Session, pair: m.Pair, predicted: Mapping[int, int | None],
                     truth_views: list[tuple[Any, Any]], refinements: Refinements | None = None) -> float:
    """Mean over the novel views of the silhouette RMSE between the predicted and the true render."""
    values = [silhouette_rmse(p[0], t[0], t[1] | p[1])
              for p, t in zip(relighter.views(session, pair, predicted, refinements), truth_views, strict=True)]
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else float("nan")


class RelightingScores:
    """The relighting error of each (pair, method) whose pair shows the exemplar's own shape
    (`relighting_eval`): the true materials' renders are made once per pair, at most `max_pairs`
    pairs per method are rendered."""

    def __init__(self, store: BlobStore, size: int, spp: int, max_pairs: int | None):
        self.store, self.size, self.spp, self.max_pairs = store, size, spp, max_pairs
        self.relighter: Any = None
        self.truth_views: dict[int, Any] = {}  # pair id -> the true render's views (None: no true render)
        self.pairs: dict[str, int] = defaultdict(int)

    def wants(self, session: Session, pair: m.Pair, method_key: str, truth: TruthEntry) -> bool:
        if self.max_pairs is not None and self.pairs[method_key] >= self.max_pairs:
            return False
        shape = session.get(m.Shape, pair.shape_id)
        return bool(truth.in_collection) and shape is not None and shape.source_id == truth.shape

    def error(self, session: Session, pair: m.Pair, method_key: str, chosen: dict[int, int | None],
              truth: TruthEntry, refinements: Refinements | None = None) -> float | None:
        """The pair's relighting error with `chosen` materials (refined where `refinements` say);
        None when no true render can be made or a render fails."""
        try:
            if self.relighter is None:
                self.relighter = Relighter(session, self.store, self.size, self.spp)
            if pair.id not in self.truth_views:
                true = true_materials(session, session.get(m.Shape, pair.shape_id), truth)
                self.truth_views[pair.id] = None if true is None else self.relighter.views(session, pair, true)
            if self.truth_views[pair.id] is None:
                return None
            value = relighting_error(self.relighter, session, pair, chosen, self.truth_views[pair.id], refinements)
        except Exception as exc:  # one unrenderable pair never stops the evaluation
            log.warning("pair %s: relighting render failed: %s", pair.id, exc)
            return None
        self.pairs[method_key] += not refinements  # the refined render of a counted pair is not another pair
        return value if math.isfinite(value) else None
