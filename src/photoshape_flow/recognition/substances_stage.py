"""Stage `substances` (section 4.3): bootstrap renders, the substance network, a substance per part.

It fans out over the bootstrap renders (item positions, as `training-renders` does); its finishing
step trains (or resumes) the network on them and assigns a substance to every aligned part. Run
whole, it does the three in order.
"""

from __future__ import annotations

from typing import Any

from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import SubstancesConfig
from photoshape_flow.recognition.substances import run_substances, train_and_assign
from photoshape_flow.recognition.training_renders import run_training_renders
from photoshape_flow.recognition.training_renders_stage import exposure_versions, pool_versions
from photoshape_flow.synth.spec import ENV_SCALE_RANGE

NAME = "substances"


def plan(ctx: StageContext, cfg: SubstancesConfig) -> list[WorkUnit]:
    return [WorkUnit("bootstrap", tuple(range(cfg.bootstrap_count)))]


def versions(ctx: StageContext, cfg: SubstancesConfig, unit: WorkUnit) -> dict[int, str]:
    return exposure_versions(pool_versions(ctx, "bootstrap", unit), ENV_SCALE_RANGE, cfg.exposure)


def run(ctx: StageContext, cfg: SubstancesConfig, work: WorkUnit | None = None) -> StageReport:
    if work is not None:
        return _bootstrap(ctx, cfg, work)
    summary = run_substances(ctx.settings, bootstrap_count=cfg.bootstrap_count, size=cfg.size, spp=cfg.spp,
                             train_config=cfg.network, progress=ctx.progress, renderer=ctx.renderer, store=ctx.store,
                             exposure=cfg.exposure)
    return _report(summary, summary["bootstrap"])


def finish(ctx: StageContext, cfg: SubstancesConfig) -> StageReport:
    """After every bootstrap unit: the network (trained or resumed) and the parts' substances."""
    summary = train_and_assign(ctx.settings, size=cfg.size, train_config=cfg.network, progress=ctx.progress,
                               store=ctx.store)
    return _report(summary, None)


def _bootstrap(ctx: StageContext, cfg: SubstancesConfig, work: WorkUnit) -> StageReport:
    renders = run_training_renders("bootstrap", cfg.bootstrap_count, cfg.size, cfg.spp, ctx.settings,
                                   renderer=ctx.renderer, indices=work.ids, progress=ctx.progress,
                                   store=ctx.store, exposure=cfg.exposure)
    counts = {k: renders.get(k) for k in ("rendered", "skipped", "rejected", "failed")}
    return StageReport(NAME, done=int(renders["rendered"]), skipped=int(renders["skipped"]),
                       failed=int(renders["failed"]), rejected=int(renders["rejected"]), details={"bootstrap": counts})


def _report(summary: dict[str, Any], renders: dict[str, Any] | None) -> StageReport:
    parts = summary["part_substances"]
    details: dict[str, Any] = {"network": summary["network"], "bn_prior": summary.get("bn_prior"),
                               "parts": parts["parts"], "unobserved": parts["unobserved"]}
    if renders is not None:
        details["bootstrap"] = {k: renders.get(k) for k in ("rendered", "skipped", "rejected", "failed")}
    return StageReport(NAME, done=int(parts["updated"]), skipped=int(parts["skipped"]), failed=int(parts["failed"]),
                       details=details)
