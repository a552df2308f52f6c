"""Fit stage: each observed part's material chosen by rendering the pair against its photo.

For every pair ranked by the newest material classifier (`assignment` rows `classifier:<id>`):

1. Lighting of the exemplar (`estimate_lighting`): every training envmap at `rotations` azimuths,
   each rendered with the classifier's rank-1 materials at the exemplar's reference pair's camera,
   exposure solved in closed form (`fit.lighting`); the lowest appearance loss wins. Stored in
   ``exemplar.meta["fit_lighting"]`` with the key of its inputs and reused by every pair of the
   exemplar until those inputs change.
2. Candidates per observed part (`fit.candidates`): the ranking's top-K, the colour-nearest material
   of every substance, every enabled material the classifier was not trained on.
3. Renders (`fit.select.render_slots`): render j puts each part's j-th candidate on it, at the pair's
   camera in the exemplar's frame; each part's render region is compared with the photo's aligned
   region (`fit.appearance.distance`) at the exposure that best explains the whole photo with that
   candidate (`fit.scene.select_profiled`), and the cost adds the ranking prior. The weights, the
   scores' temperature and the blur are fitted per classifier on validation renders
   (`fitting.calibration`, D34) before the first pair; the profile's hand-set ones are the fallback.
4. Rows `method="fit"`, ``method_key="fit:<classifier id>"``, ranked by cost, next to the
   classifier's and the baselines'. Unobserved parts keep the classifier's ranking (copied).
5. Refinement (`fitting.refine`, `fit.refine`) of the winners of the pairs that are used
   (publish's and each exemplar's best): each part's tint solved against the photo like for like,
   and, as options, a roughness scale and a UV placement, on the rank-1 rows' ``refinement``.

The run's context and each pair's scene are read by `fitting.context` (shared with the
calibration). Resumable: each pair's rows carry a hash of the config, the code version, the classifier rows they
start from, the candidate set and the lighting key; a pair whose hash is unchanged is skipped, and
pairs are claimed one at a time (`work_claim`, stage ``fit:<method_key>``) like inference's.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import claims
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.fit.candidates import Candidate
from photoshape_flow.fit.select import rank_candidates, scores_of
from photoshape_flow.fitting.calibration import ensure_calibration
from photoshape_flow.fitting.context import (
    METHOD,
    FitContext,
    PairData,
    load_pair,
    reference_pair,
    weights_report,
)
from photoshape_flow.fitting.pairs import fit_pairs_of
from photoshape_flow.fitting.refine import is_refined, refine_rows
from photoshape_flow.fitting.steps import candidates_of, lighting_estimate, select_materials
from photoshape_flow.hashing import stable_hash
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.profiles import FitConfig
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.recognition.inference import IDENTITY_UV
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store

log = logging.getLogger(__name__)

LIGHTING_KEY = "fit_lighting"  # exemplar.meta entry


@dataclass
class FitSummary:
    method_key: str | None
    pairs_done: int = 0
    pairs_skipped: int = 0
    pairs_failed: list[tuple[int, str]] = field(default_factory=list)
    # pairs another live worker holds: reported as blocked, so `run all` stops (or `--wait`s) before
    # publish, which would otherwise show those pairs without their fit rows and publish them again later
    blocked: list[claims.Hold] = field(default_factory=list)
    rows: int = 0
    lightings: int = 0  # lighting estimates computed (not reused)
    changed: int = 0  # parts whose first material differs from the classifier's
    refined: int = 0  # parts whose winner was refined (`fitting.refine`)
    refined_pairs: int = 0
    # wall seconds per phase (calibration, reading, lighting, selection, refinement): issue 26 item 7's
    # budgets are per phase (selection per pair, lighting per exemplar, refinement per refined pair)
    seconds: dict[str, float] = field(default_factory=dict)
    weights: dict[str, Any] = field(default_factory=dict)  # the cost weights used: fitted or hand-set (D34)

    @contextmanager
    def timed(self, phase: str) -> Iterator[None]:
        """Adds the block's wall time to `seconds[phase]`, also when it raises."""
        started = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - started

    def per_unit(self) -> dict[str, float | None]:
        """Seconds per unit of each phase's budget: selection per fitted pair, lighting per estimate,
        refinement per refined pair (None where nothing of that unit was done)."""
        def ratio(phase: str, count: int) -> float | None:
            return round(self.seconds.get(phase, 0.0) / count, 3) if count else None

        return {"selection_per_pair": ratio("selection", self.pairs_done),
                "lighting_per_exemplar": ratio("lighting", self.lightings),
                "refinement_per_refined_pair": ratio("refinement", self.refined_pairs)}


def rows_hash(session: Session, pair_id: int, method_key: str) -> str | None:
    """The params_hash a pair's rows of `method_key` carry (None: no rows)."""
    return session.execute(
        sa.select(m.Assignment.params_hash).where(m.Assignment.pair_id == pair_id,
                                                  m.Assignment.method_key == method_key).limit(1)
    ).scalar_one_or_none()


def exemplar_lighting(session: Session, ctx: FitContext, data: PairData) -> tuple[dict[str, Any], bool]:
    """The exemplar's stored lighting when its key still holds, else a fresh estimate (stored); (record, computed)."""
    exemplar = session.get(m.Exemplar, data.pair.exemplar_id)
    assert exemplar is not None
    reference = reference_pair(session, ctx, exemplar.id) or data.pair
    stored = (exemplar.meta or {}).get(LIGHTING_KEY)
    for pair in dict.fromkeys((reference, data.pair)):  # the pair itself when its reference cannot be lit
        key = ctx.lighting_key(pair.id, data.source_hash if pair.id == data.pair.id
                               else rows_hash(session, pair.id, ctx.source_key))
        if isinstance(stored, dict) and stored.get("key") == key:
            return stored, False
        try:
            light = lighting_estimate(ctx, data if pair.id == data.pair.id else load_pair(session, ctx, pair))
        except ValueError as exc:
            if pair.id == data.pair.id:
                raise
            log.warning("fit: exemplar %s: its reference pair %s cannot be lit (%s); lighting pair %s instead",
                        exemplar.id, pair.id, exc, data.pair.id)
            continue
        record = {**light, "pair_id": pair.id, "key": key}
        exemplar.meta = {**(exemplar.meta or {}), LIGHTING_KEY: record}
        return record, True
    raise AssertionError("unreachable: the pair itself is always tried")


# -- one pair --------------------------------------------------------------------------------------------
def pair_hash(ctx: FitContext, data: PairData, candidates: dict[int, list[Candidate]], lighting_key: str,
              refine: bool = False) -> str:
    """The hash a pair's fit rows carry: config, code, the ranking they start from, the candidates, the lighting,
    and whether its winners are refined (`fitting.refine`)."""
    return stable_hash({**ctx.params, "ranking": data.source_hash, "lighting": lighting_key, "refine": refine,
                        "candidates": {str(i): [c.material_id for c in cs] for i, cs in sorted(candidates.items())}})


def fit_rows(ctx: FitContext, data: PairData, candidates: dict[int, list[Candidate]],
             measured: dict[int, dict[int, float | None]], exposure: float, params_hash: str) -> list[m.Assignment]:
    """The pair's `fit` rows: observed parts ranked by cost, the others' classifier ranking copied."""
    out = []
    for index, rows in sorted(data.rows.items()):
        base = rows[0]
        common = {"pair_id": data.pair.id, "part_id": base.part_id, "method": METHOD, "method_key": ctx.method_key,
                  "classifier_id": ctx.classifier.id, "params_hash": params_hash}
        if index not in candidates:
            for row in rows:
                out.append(m.Assignment(**common, rank=row.rank, material_id=row.material_id, score=row.score,
                                        posterior=row.posterior, substance=row.substance, unobserved=row.unobserved,
                                        params={**(row.params or {}), "fit": {"source": "ranking-only"}}))
            continue
        ranked = rank_candidates(candidates[index], measured.get(index, {}), ctx.prior_weight)
        for rank, (item, score) in enumerate(zip(ranked, scores_of(ranked, ctx.temperature), strict=True), start=1):
            c = item.candidate
            out.append(m.Assignment(
                **common, rank=rank, material_id=c.material_id, score=score, substance=c.substance, unobserved=False,
                posterior=score if ctx.calibration is not None else None,  # calibrated only with fitted weights
                params={"uv": IDENTITY_UV, "part_substance": (base.params or {}).get("part_substance"),
                        "fit": {"source": c.source, "prior": round(c.prior, 6), "cost": round(item.cost, 6),
                                "distance": None if item.distance is None else round(item.distance, 6),
                                "exposure": round(exposure, 6)}},
            ))
    return out


def changed_parts(data: PairData, rows: Sequence[m.Assignment]) -> int:
    """How many parts' first material the fit rows change from the classifier's (what a run reports)."""
    first = {ranked[0].part_id: ranked[0].material_id for ranked in data.rows.values() if ranked}
    return sum(1 for r in rows if r.rank == 1 and r.material_id != first.get(r.part_id))


# -- the run ---------------------------------------------------------------------------------------------
def run_fit(cfg: FitConfig, *, pair_ids: Sequence[int] | None = None, settings: Settings | None = None,
            renderer: RendererProtocol | None = None, classifier_id: int | None = None,
            progress: Progress | None = None, store: BlobStore | None = None) -> FitSummary:
    """Fit every pending pair (see the module docstring); resumable and idempotent, one bad pair never stops it."""
    settings = settings or get_settings()
    store = store if store is not None else default_store(settings)
    url = settings.resolved_database_url
    with session_scope(url) as session:
        classifier = resolve_classifier(session, classifier_id)
        if classifier is None:
            log.warning("fit: no trained material classifier yet; nothing to fit")
            return FitSummary(None)
        ctx = FitContext(session, store, classifier, cfg, renderer)
        todo = fit_pairs_of(session, ctx.source_key, pair_ids)
    summary = FitSummary(ctx.method_key)
    if todo:
        try:
            with summary.timed("calibration"):
                ctx.calibration = ensure_calibration(ctx, settings, progress)
        except Exception as exc:  # the hand-set weights still rank; the report and the log say why
            log.warning("fit: calibration failed (%s: %s); hand-set weights", type(exc).__name__, exc)
            summary.weights["error"] = f"{type(exc).__name__}: {exc}"[:500]
    summary.weights = {**weights_report(ctx), **summary.weights}
    stage = f"{METHOD}:{ctx.method_key}"
    for pair_id in counted(progress, "fit pairs", todo):
        try:
            with session_scope(url) as session:
                pair = session.get(m.Pair, pair_id)
                assert pair is not None
                with summary.timed("reading"):
                    data = load_pair(session, ctx, pair)
                    candidates = candidates_of(ctx, data)
                # nothing observed: the ranking is copied, no lighting needed
                with summary.timed("lighting"):
                    light, computed = exemplar_lighting(session, ctx, data) if candidates else ({"key": None}, False)
                summary.lightings += int(computed)
                refine = bool(candidates) and is_refined(session, ctx, pair)
                digest = pair_hash(ctx, data, candidates, str(light["key"]), refine)
                if rows_hash(session, pair_id, ctx.method_key) == digest:
                    summary.pairs_skipped += 1
                    continue
                if not claims.claim(session, stage, [str(pair_id)], params_hash=digest,
                                    lease_seconds=settings.claim_lease_seconds, retry_failed=True):
                    held = claims.live_holds(session, stage, [str(pair_id)])
                    summary.blocked += held
                    summary.pairs_skipped += int(not held)
                    continue
            with session_scope(url) as session:
                with summary.timed("selection"):
                    measured, exposure = select_materials(ctx, data, candidates, light)
                    rows = fit_rows(ctx, data, candidates, measured, exposure, digest)
                if refine:
                    with summary.timed("refinement"):
                        summary.refined += refine_rows(ctx, data, rows, light, exposure)
                    summary.refined_pairs += 1
                session.execute(sa.delete(m.Assignment).where(m.Assignment.pair_id == pair_id,
                                                              m.Assignment.method_key == ctx.method_key))
                session.add_all(rows)
                claims.complete(session, stage, [str(pair_id)])
            summary.pairs_done += 1
            summary.rows += len(rows)
            summary.changed += changed_parts(data, rows)
        except Exception as exc:  # one bad pair never stops the batch
            reason = f"{type(exc).__name__}: {exc}"
            log.warning("fit: pair %s failed: %s", pair_id, reason)
            summary.pairs_failed.append((pair_id, reason))
            with session_scope(url) as session:
                claims.fail(session, stage, str(pair_id), reason)
    log.info("fit %s: %d pairs, %d rows, %d parts changed, %d refined, %d skipped, %d failed, %d lighting estimates; "
             "seconds %s", ctx.method_key, summary.pairs_done, summary.rows, summary.changed, summary.refined,
             summary.pairs_skipped, len(summary.pairs_failed), summary.lightings,
             {k: round(v, 1) for k, v in summary.seconds.items()})
    return summary
