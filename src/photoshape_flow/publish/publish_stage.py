"""Stage `publish`: PhotoShape renders and exports of the best pairs of every shape, then the gallery."""

from __future__ import annotations

from pathlib import Path

import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import PublishConfig
from photoshape_flow.publish.builtin_renders import run_builtin_renders
from photoshape_flow.publish.gallery_site import write_gallery_site
from photoshape_flow.publish.photoshapes import assignment_set_keys, candidate_method_keys
from photoshape_flow.publish.publish import run_publish

NAME = "publish"


def gallery_dir(ctx: StageContext) -> Path:
    return ctx.settings.data_root / "gallery"


def plan(ctx: StageContext, cfg: PublishConfig) -> list[WorkUnit]:
    """Pairs up to the configured rank of their shape (excluded pairs never)."""
    with ctx.session() as session:
        ids = session.execute(
            sa.select(m.Pair.id).where(m.Pair.rank <= cfg.max_rank, ~m.Pair.exclude).order_by(m.Pair.id)
        ).scalars()
        return [WorkUnit("pairs", tuple(ids))]


def versions(ctx: StageContext, cfg: PublishConfig, unit: WorkUnit) -> dict[int, str]:
    """Each pair's rank-1 assignment-set key of the method it is published with (`publish.method`: the
    pair's newest `classifier:<id>` or `fit:<id>` rows).

    A new classifier's, a re-ranked or a re-fitted assignment changes the key, so the pair is claimed
    and rendered again, by `photoshape run publish` and the Prefect deployment alike.
    """
    with ctx.session() as session:
        shown = candidate_method_keys(session, cfg.method, unit.ids)
        keys = assignment_set_keys(session, shown)
    return {pair_id: keys[(pair_id, method_key)] for pair_id, method_key in shown if (pair_id, method_key) in keys}


def run(ctx: StageContext, cfg: PublishConfig, work: WorkUnit | None = None) -> StageReport:
    ids = list(work.ids) if work is not None else list(plan(ctx, cfg)[0].ids)
    summary = run_publish(ids, cfg.method, ctx.settings, views=cfg.views, size=cfg.size, spp=cfg.spp,
                          formats=cfg.formats, renderer=ctx.renderer, progress=ctx.progress, store=ctx.store)
    report = StageReport(NAME, done=summary.rendered, skipped=summary.skipped, failed=summary.failed,
                         details={"publish": summary.as_dict()})
    if work is None:
        report = report.merge(finish(ctx, cfg))
    return report


def finish(ctx: StageContext, cfg: PublishConfig) -> StageReport:
    """The built-in render of every candidate publish leaves waiting (beyond `max_rank`, at thumbnail
    quality: the candidates page shows photo and shape side by side), then the gallery site over
    everything published so far with `publish.method`."""
    with ctx.session() as session:
        planned = set(plan(ctx, cfg)[0].ids)
        waiting = [pair_id for pair_id, _ in candidate_method_keys(session, cfg.method) if pair_id not in planned]
    builtins = run_builtin_renders(waiting, ctx.settings, renderer=ctx.renderer, progress=ctx.progress,
                                   store=ctx.store)
    site = write_gallery_site(gallery_dir(ctx), cfg.method, ctx.settings, progress=ctx.progress, store=ctx.store)
    return StageReport(NAME, done=builtins.rendered, skipped=builtins.skipped, failed=builtins.failed,
                       details={"gallery": str(site.index), "gallery_published": site.published,
                                "gallery_waiting": site.waiting, "method": cfg.method,
                                "builtin_renders": {"rendered": builtins.rendered, "skipped": builtins.skipped,
                                                    "failed": builtins.failed, "errors": builtins.errors}})
