"""Stage `inference` (section 6.1): ranked materials per part, for ours and every baseline.

Each method is a part of the fan-out; the pipeline claims each pair itself (per method and
classifier, keyed by the pair's own hash), so the generic batch claim is skipped for this stage.
"""

from __future__ import annotations

import logging

from photoshape_flow.db import models as m
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.progress import active_pairs
from photoshape_flow.pipeline.report import StageReport, blocked_by
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import InferenceConfig
from photoshape_flow.recognition.inference import run_inference

NAME = "inference"
log = logging.getLogger(__name__)


def methods_to_run(ctx: StageContext, cfg: InferenceConfig) -> list[str]:
    """The configured methods; the classifier only once one is trained."""
    out = []
    for method in cfg.methods:
        if method == "classifier":
            with ctx.session() as session:
                if resolve_classifier(session) is None:
                    log.warning("inference: no trained material classifier yet; skipping method 'classifier'")
                    continue
        out.append(method)
    return out


def plan(ctx: StageContext, cfg: InferenceConfig) -> list[WorkUnit]:
    with ctx.session() as session:
        ids = tuple(session.execute(active_pairs().order_by(m.Pair.id)).scalars())
    return [WorkUnit(method, ids) for method in methods_to_run(ctx, cfg)]


def run(ctx: StageContext, cfg: InferenceConfig, work: WorkUnit | None = None) -> StageReport:
    if work is None:
        report = StageReport(NAME)
        for method in methods_to_run(ctx, cfg):
            report = report.merge(_run_method(ctx, cfg, method, None))
        return report
    return _run_method(ctx, cfg, work.part, list(work.ids))


def _run_method(ctx: StageContext, cfg: InferenceConfig, method: str, pair_ids: list[int] | None) -> StageReport:
    summary = run_inference(method, pair_ids=pair_ids, top_k=cfg.top_k, settings=ctx.settings, progress=ctx.progress,
                            store=ctx.store)
    return StageReport(
        NAME, done=summary.pairs_done, skipped=summary.pairs_skipped, failed=len(summary.pairs_failed),
        blocked=blocked_by(summary.blocked),
        details={summary.method_key: {"pairs": summary.pairs_done, "rows": summary.rows,
                                      "failed": summary.pairs_failed[:20]}},
    )
