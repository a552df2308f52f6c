"""Stage `training-renders` (section 5.1): randomized renders conditioned on part substances.

It fans out over item positions (the round's train items, then its validation items): each unit
renders its positions, so workers on the work pool or Dask processes share the heaviest work of a
paper-scale run (156k renders) without rendering an item twice.
"""

from __future__ import annotations

from typing import Any

from photoshape_flow.db import models as m
from photoshape_flow.hashing import stable_hash
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import TrainingRendersConfig
from photoshape_flow.recognition.render_pools import load_pools
from photoshape_flow.recognition.training_renders import run_training_renders
from photoshape_flow.synth.spec import ENV_SCALE_RANGE

NAME = "training-renders"


def plan(ctx: StageContext, cfg: TrainingRendersConfig) -> list[WorkUnit]:
    return [WorkUnit("training", tuple(range(cfg.count)))]


def pools_digest(session: Any, round: str) -> str:
    """A key of everything an item's spec and pixels are drawn from (pools, material, envmap and mesh blobs).

    Work claims of the render stages are versioned by it: when materials, envmaps, shapes or part
    substances change, done items are re-opened and the render stage's own per-item hash decides
    what to redo (items whose spec did not change are skipped).
    """
    from dataclasses import asdict

    import sqlalchemy as sa


    try:
        pools = asdict(load_pools(session, round))  # type: ignore[arg-type]
    except ValueError as exc:  # nothing to render: the run reports it
        return stable_hash({"error": str(exc)})
    pools.pop("warnings", None)
    blobs = {
        "materials": session.execute(sa.select(m.Material.id, m.Material.params_hash).order_by(m.Material.id)).all(),
        "envmaps": session.execute(sa.select(m.Envmap.id, m.Envmap.blob).order_by(m.Envmap.id)).all(),
        "shapes": session.execute(sa.select(m.Shape.id, m.Shape.mesh_blob).order_by(m.Shape.id)).all(),
    }
    return stable_hash({"pools": pools, "blobs": {k: [list(r) for r in v] for k, v in blobs.items()}})


def pool_versions(ctx: StageContext, round_: str, unit: WorkUnit) -> dict[int, str]:
    """Every item of a render unit (`round_`: training or bootstrap) carries the digest of the pools
    its spec is drawn from; the substances stage shares it for its bootstrap renders."""
    with ctx.session() as session:
        digest = pools_digest(session, round_)
    return dict.fromkeys(unit.ids, digest)


def exposure_versions(found: dict[int, str], env_scale_range: tuple[float, float], exposure: str) -> dict[int, str]:
    """The pools' digests, joined by the exposure settings when they are not the defaults (so changing
    them re-opens done items, and databases made before they were settings keep their versions)."""
    if tuple(env_scale_range) == ENV_SCALE_RANGE and exposure == "as-is":
        return found
    return {item: stable_hash([digest, list(env_scale_range), exposure]) for item, digest in found.items()}


def versions(ctx: StageContext, cfg: TrainingRendersConfig, unit: WorkUnit) -> dict[int, str]:
    return exposure_versions(pool_versions(ctx, "training", unit), cfg.env_scale_range, cfg.exposure)


def run(ctx: StageContext, cfg: TrainingRendersConfig, work: WorkUnit | None = None) -> StageReport:
    summary = run_training_renders("training", cfg.count, cfg.size, cfg.spp, ctx.settings, renderer=ctx.renderer,
                                   env_scale_range=tuple(cfg.env_scale_range), exposure=cfg.exposure,
                                   indices=None if work is None else work.ids, progress=ctx.progress,
                                   store=ctx.store)
    return StageReport(
        NAME, done=int(summary["rendered"]), skipped=int(summary["skipped"]), failed=int(summary["failed"]),
        rejected=int(summary["rejected"]),
        details={"requested": summary["requested"], "splits": summary["splits"]},
    )
