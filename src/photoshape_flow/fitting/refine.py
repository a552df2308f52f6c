"""The fit stage's refinement step (`fit.refine`) on the database's pairs: which pairs, and the rows it fills.

Only the pairs that are used are refined (issue 26: refinement costs seconds per pair): those
publish renders (rank up to `FitConfig.refine_max_rank` among the shape's exemplars) and each
exemplar's best pair (the one that lights it, `fitting.context.reference_pair`); every other pair
keeps the selection. The refinement is written on the rank-1 `fit` row of each refined part
(``assignment.refinement``), and whether a pair is refined enters its params_hash
(`fitting.fit.pair_hash`), so a pair that becomes used is fitted again.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.fit.refine import RefineSettings, refine_parts
from photoshape_flow.fit.scene import FrameRenderer
from photoshape_flow.fitting.context import reference_pair
from photoshape_flow.profiles import FitConfig


def refine_settings(cfg: FitConfig) -> RefineSettings:
    return RefineSettings(iterations=cfg.refine_iterations, spp=cfg.refine_spp, erode=cfg.erode, uv=cfg.refine_uv)


def is_refined(session: Session, ctx: Any, pair: m.Pair) -> bool:
    """Whether the fit refines this pair's winners (see the module docstring)."""
    if not ctx.cfg.refine:
        return False
    if pair.rank <= ctx.cfg.refine_max_rank:
        return True
    reference = reference_pair(session, ctx, pair.exemplar_id)
    return reference is not None and reference.id == pair.id


def refine_rows(ctx: Any, data: Any, rows: Sequence[m.Assignment], light: dict[str, Any], exposure: float) -> int:
    """Refine the pair's observed winners in one set of renders; set their rank-1 rows' ``refinement``.

    Returns the number of parts refined. Unobserved parts and built-in winners are rendered as chosen
    but not refined.
    """
    first = {r.part_id: r for r in rows if r.rank == 1}
    index_of = {ranked[0].part_id: index for index, ranked in data.rows.items() if ranked}
    chosen = {index_of[pid]: row for pid, row in first.items() if pid in index_of}
    observed = [i for i, row in chosen.items() if (row.params or {}).get("fit", {}).get("cost") is not None
                and row.material_id is not None]
    if not observed:
        return 0
    materials = [ctx.spec(chosen[p.index].material_id) if p.index in chosen else None for p in data.scene.mesh.parts]
    envmap = ctx.light_envmap(light)
    renderer, cfg = ctx.frame.renderer, ctx.cfg
    frame = FrameRenderer(renderer, cfg.refine_size, cfg.refine_spp)
    uv_frame = FrameRenderer(renderer, cfg.size, cfg.refine_spp)  # the photo's frame; refine_spp: measured
    settings = refine_settings(cfg)  # faster and no worse than fit.spp (docs/benchmarks.md)
    result = refine_parts(frame, data.scene, materials, observed, envmap, exposure, settings, uv_frame=uv_frame)
    for index, refined in result.items():
        chosen[index].refinement = {**refined.to_dict(), "iterations": settings.iterations, "spp": settings.spp}
    return len(result)
