"""The own-shape pairs of an evaluation world with every part in its true library material: what
`light_convention.py` and `render_gap.py` render under the truth's light (read-only, never committed)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.evaluation.groundtruth import TruthEntry, read_groundtruth_file
from photoshape_flow.fitting.context import FitContext, PairData, load_pair
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.render import EnvmapSpec
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore


@dataclass
class TrueScene:
    """A pair of the exemplar's own shape: its fit data, part names, true materials and the truth's light."""

    pair: m.Pair
    exemplar: m.Exemplar
    truth: TruthEntry
    data: PairData
    names: dict[int, str]  # part index -> name
    materials: list[Any]  # render spec per mesh part (None: not in the truth)
    hdri: Path  # the truth's envmap file

    def light(self, rotation: float | None = None, hdri: Path | None = None) -> EnvmapSpec:
        """The truth's light (another file or turn when given), at the truth's strength."""
        light = self.truth.lighting
        assert light is not None
        turn = light.rotation if rotation is None else rotation
        return EnvmapSpec(hdri or self.hdri, scale=light.scale, rotation=turn)


def fit_context(session: Session, settings: Settings, size: int = 128, spp: int = 32) -> FitContext:
    """The small profile's fit context around the data root's classifier, at `size` pixels and `spp`."""
    cfg = replace(resolve_profile("small", []).profile.fit, size=size, spp=spp)
    return FitContext(session, BlobStore(settings.blob_root), resolve_classifier(session), cfg)


def true_scenes(session: Session, ctx: FitContext, groundtruth: Path, source: str,
                envmap_dir: Path) -> Iterator[TrueScene]:
    """Every own-shape pair with a lighting truth and a fit-ready alignment, in pair order."""
    by_name = {mat.name: mat.id for mat in ctx.material_rows.values()}
    truths = match_groundtruth(session, read_groundtruth_file(groundtruth), source).truths
    shapes = {(s.source, s.source_id): s.id for s in session.execute(sa.select(m.Shape)).scalars()}
    pairs = session.execute(sa.select(m.Pair).where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)
                            .order_by(m.Pair.id)).scalars().all()
    for pair in pairs:
        truth = truths[pair.exemplar_id]
        own = shapes.get((truth.shape_ref.source, truth.shape_ref.source_id)) == pair.shape_id
        if not own or truth.lighting is None:
            continue
        try:
            data = load_pair(session, ctx, pair)
        except ValueError:
            continue
        names = dict(session.execute(sa.select(m.Part.index, m.Part.name)
                                     .where(m.Part.shape_id == pair.shape_id)).all())
        materials = [ctx.spec(by_name.get(truth.parts[names[p.index]].material))
                     if names.get(p.index) in truth.parts else None for p in data.scene.mesh.parts]
        exemplar = session.get(m.Exemplar, pair.exemplar_id)
        yield TrueScene(pair, exemplar, truth, data, names, materials, envmap_dir / Path(truth.lighting.envmap).name)
