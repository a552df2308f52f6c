"""Stage `fit`: each observed part's material chosen by rendering it against the photo (`fitting.fit`).

Fans out over the pairs the newest material classifier ranked; the pipeline claims each pair itself
(keyed by the pair's own hash: candidates, lighting, config), so the generic batch claim is skipped.
"""

from __future__ import annotations

from photoshape_flow.fitting.fit import run_fit
from photoshape_flow.fitting.pairs import fit_pairs_of
from photoshape_flow.method_keys import MethodKey
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport, blocked_by
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import FitConfig

NAME = "fit"


def plan(ctx: StageContext, cfg: FitConfig) -> list[WorkUnit]:
    """The pairs with rows of the newest classifier (none before one is trained)."""
    with ctx.session() as session:
        classifier = resolve_classifier(session)
        if classifier is None:
            return []
        return [WorkUnit("pairs", tuple(fit_pairs_of(session, str(MethodKey.for_classifier(classifier.id)))))]


def run(ctx: StageContext, cfg: FitConfig, work: WorkUnit | None = None) -> StageReport:
    summary = run_fit(cfg, pair_ids=None if work is None else list(work.ids), settings=ctx.settings,
                      renderer=ctx.renderer, progress=ctx.progress, store=ctx.store)
    return StageReport(
        NAME, done=summary.pairs_done, skipped=summary.pairs_skipped, failed=len(summary.pairs_failed),
        blocked=blocked_by(summary.blocked),
        # counts and seconds only (per-unit rates are seconds over counts): batches' reports add up
        details={summary.method_key or "fit": {"pairs": summary.pairs_done, "rows": summary.rows,
                                               "parts_changed": summary.changed, "parts_refined": summary.refined,
                                               "refined_pairs": summary.refined_pairs,
                                               "lightings": summary.lightings, "weights": summary.weights,
                                               "seconds": {k: round(v, 2) for k, v in summary.seconds.items()},
                                               "failed": summary.pairs_failed[:20]}},
    )
