"""Stage `substances` (section 4.3): bootstrap renders, the substance network, a substance per part."""

from __future__ import annotations

from photoshape_flow.profiles import SubstancesConfig
from photoshape_flow.stages.context import StageContext
from photoshape_flow.stages.report import StageReport

NAME = "substances"


def run(ctx: StageContext, cfg: SubstancesConfig, work: None = None) -> StageReport:
    from photoshape_flow.pipeline.substances import run_substances

    summary = run_substances(ctx.settings, bootstrap_count=cfg.bootstrap_count, size=cfg.size, spp=cfg.spp,
                             train_config=cfg.network)
    parts = summary["part_substances"]
    renders = summary["bootstrap"]
    return StageReport(
        NAME, done=int(parts["updated"]), skipped=int(parts["skipped"]), failed=int(parts["failed"]),
        details={"bootstrap": {k: renders.get(k) for k in ("rendered", "skipped", "rejected", "failed")},
                 "network": summary["network"], "parts": parts["parts"], "unobserved": parts["unobserved"]},
    )
