"""Stage `fine-alignment` (section 4.2): each pair's part map flow-warped onto its exemplar, CRF-cleaned."""

from __future__ import annotations

from photoshape_flow.align.fine import FineParams
from photoshape_flow.alignment.fine_alignment import expected_hashes, run_fine_alignment
from photoshape_flow.db import models as m
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.progress import active_pairs
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import FineAlignmentConfig

NAME = "fine-alignment"


def plan(ctx: StageContext, cfg: FineAlignmentConfig) -> list[WorkUnit]:
    with ctx.session() as session:
        return [WorkUnit("pairs", tuple(session.execute(active_pairs().order_by(m.Pair.id)).scalars()))]


def versions(ctx: StageContext, cfg: FineAlignmentConfig, unit: WorkUnit) -> dict[int, str]:
    """Each pair's expected alignment hash (mesh, exemplar, camera): a moved camera re-opens the pair."""
    with ctx.session() as session:
        return expected_hashes(session, unit.ids, FineParams(size=cfg.size))


def run(ctx: StageContext, cfg: FineAlignmentConfig, work: WorkUnit | None = None) -> StageReport:
    summary = run_fine_alignment(None if work is None else list(work.ids), ctx.settings,
                                 params=FineParams(size=cfg.size), renderer=ctx.renderer, progress=ctx.progress,
                                 store=ctx.store)
    return StageReport(NAME, done=int(summary["aligned"]), skipped=int(summary["up_to_date"]),
                       failed=int(summary["failed"]),
                       details={"failures": summary.get("failures", [])[:20]})
