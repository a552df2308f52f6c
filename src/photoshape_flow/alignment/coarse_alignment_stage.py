"""Stage `coarse-alignment` (section 4.1): view and exemplar descriptors, then exact retrieval -> pairs.

It fans out over two parts, shapes (viewpoint sweeps, the heavy part) and exemplars; `finish`
searches all descriptors and rewrites the pairs of the shapes whose neighbours changed.
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa

from photoshape_flow.alignment import coarse_alignment as coarse
from photoshape_flow.alignment.coarse_alignment import CoarseConfig, compute_pairs
from photoshape_flow.db import models as m
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import CoarseAlignmentConfig

NAME = "coarse-alignment"


def _config(cfg: CoarseAlignmentConfig) -> Any:
    return CoarseConfig(exemplar_topk=cfg.exemplar_topk, shape_topn=cfg.shape_topn)


def _features_report(part: str, counts: dict[str, Any]) -> StageReport:
    return StageReport(NAME, done=int(counts["computed"]), skipped=int(counts["skipped"]),
                       failed=int(counts["failed"]),
                       details={part: {k: v for k, v in counts.items() if k != "errors"}})


def plan(ctx: StageContext, cfg: CoarseAlignmentConfig) -> list[WorkUnit]:
    units = []
    with ctx.session() as session:
        for part, model in (("shapes", m.Shape), ("exemplars", m.Exemplar)):
            ids = session.execute(
                sa.select(model.id).where(model.status == "ok", ~model.exclude).order_by(model.id)
            ).scalars()
            units.append(WorkUnit(part, tuple(ids)))
    return units


def versions(ctx: StageContext, cfg: CoarseAlignmentConfig, unit: WorkUnit) -> dict[int, str]:
    """A shape's mesh blob, an exemplar's image and mask blobs: re-ingesting new content re-opens the item."""
    columns = {"shapes": (m.Shape, m.Shape.mesh_blob), "exemplars": (m.Exemplar, m.Exemplar.image_blob)}
    model, blob = columns[unit.part]
    extra = m.Exemplar.mask_blob if unit.part == "exemplars" else sa.literal("")
    with ctx.session() as session:
        rows = session.execute(sa.select(model.id, blob, extra).where(model.id.in_(list(unit.ids))))
        return {int(i): f"{a}/{b}" for i, a, b in rows}


def run(ctx: StageContext, cfg: CoarseAlignmentConfig, work: WorkUnit | None = None) -> StageReport:
    config = _config(cfg)
    if work is None:
        report = _features_report("shapes", coarse.compute_view_features(
            config=config, settings=ctx.settings, renderer=ctx.renderer, progress=ctx.progress, store=ctx.store))
        report = report.merge(_features_report("exemplars", coarse.compute_exemplar_features(
            config=config, settings=ctx.settings, progress=ctx.progress, store=ctx.store)))
        report = report.merge(finish(ctx, cfg))
        return report
    if work.part == "shapes":
        counts = coarse.compute_view_features(list(work.ids), config=config, settings=ctx.settings,
                                              renderer=ctx.renderer, progress=ctx.progress, store=ctx.store)
    elif work.part == "exemplars":
        counts = coarse.compute_exemplar_features(list(work.ids), config=config, settings=ctx.settings,
                                                  progress=ctx.progress, store=ctx.store)
    else:
        raise ValueError(f"{NAME} has no part {work.part!r}")
    return _features_report(work.part, counts)


def finish(ctx: StageContext, cfg: CoarseAlignmentConfig) -> StageReport:
    """Exact retrieval over all descriptors, inverted into per-shape pairs."""
    pairs = compute_pairs(config=_config(cfg), settings=ctx.settings, store=ctx.store)
    return StageReport(NAME, details={"pairs": pairs})
