"""`photoshape eval`: compare what the pipeline recorded with a ground-truth file.

The file is the format of docs/evaluation.md (`evaluation.groundtruth`; the demo writes its own
ground truth in it, so the demo is scored by this same path). Every stage's metrics land in the
`evaluation` table as (run, stage, method, metric, value, count), tagged with the file's sha256, so
runs can be compared in SQL. Stages:

- coarse-alignment: shape recall@1/@5, median pose error, silhouette IoU for the nearest-shape case.
- fine-alignment: part-label accuracy after coarse, flow and CRF (and silhouette IoU).
- substances: accuracy of each observed part's substance against the substance that covers most of
  the part's pixels in the ground truth (pairs excluded from the pipeline are not scored).
- training: the classifier's validation metrics (the paper's Table 4 columns).
- inference: per method (ours and every baseline) per-part material top-1/top-5 and substance
  accuracy — the ground-truth material of a part is the one covering most of its aligned pixels (and its
  ground-truth substance the one covering most, as for the substances stage), so pairs with a merely
  similar shape are scored too — and the re-render error of the PhotoShape at the
  exemplar's camera inside the exemplar's mask (RMSE and SSIM).

Without a mask an entry's parts are scored by name, on the pairs whose shape is the exemplar's true
one (a part's truth is then the entry's part of the same name); pose error needs a camera and
part-label accuracy a part mask, so entries without them simply do not count there.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.alignment.coarse_alignment import evaluate_coarse_alignment
from photoshape_flow.alignment.fine_alignment import evaluate_fine_alignment
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.evaluation.bootstrap import OBSERVATIONS, Observations, difference_interval, mean_interval
from photoshape_flow.evaluation.groundtruth import TruthEntry, read_groundtruth_file
from photoshape_flow.method_keys import CLASSIFIER, classifier_id_of, method_of
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.scoring.groundtruth_registry import register_groundtruth
from photoshape_flow.scoring.relighting_eval import RelightingScores
from photoshape_flow.scoring.rerender_eval import RerenderScores, rendered_variants
from photoshape_flow.scoring.truths import pair_truths
from photoshape_flow.store import BlobStore, default_store

log = logging.getLogger(__name__)

EVAL_STAGES: tuple[str, ...] = ("coarse-alignment", "fine-alignment", "substances", "training", "inference")


@dataclass(frozen=True)
class Metric:
    stage: str
    method: str
    metric: str
    value: float | None
    count: int | None = None
    low: float | None = None  # 95% bootstrap interval over exemplars (evaluation.bootstrap), where one exists
    high: float | None = None


def estimated(stage: str, method: str, metric: str, obs: Observations) -> Metric:
    """A mean over exemplars' observations with its bootstrap interval."""
    est = mean_interval(obs)
    return Metric(stage, method, metric, est.value, est.count, est.low, est.high)


# --- stages ----------------------------------------------------------------------------------------

def evaluate_substances(session: Session, store: BlobStore, truths: dict[int, TruthEntry]) -> list[Metric]:
    return [estimated("substances", "substance-network", "part_substance_accuracy",
                      part_substance_hits(session, store, truths))]


def part_substance_hits(session: Session, store: BlobStore, truths: dict[int, TruthEntry]) -> dict[int, list[float]]:
    """Per exemplar, 1 or 0 for each observed part the substances stage labelled, against its truth."""
    correct: dict[int, list[float]] = defaultdict(list)
    rows = session.execute(
        sa.select(m.PartSubstance, m.Pair, m.Part, m.Alignment, m.Exemplar)
        .join(m.Pair, m.Pair.id == m.PartSubstance.pair_id)
        .join(m.Part, m.Part.id == m.PartSubstance.part_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .join(m.Alignment, sa.and_(m.Alignment.pair_id == m.Pair.id, m.Alignment.method == "flow-crf"))
        .where(m.PartSubstance.observed, m.Alignment.status == "ok", m.Pair.exemplar_id.in_(list(truths)),
               ~m.Pair.exclude)
    ).all()
    cache: dict[int, dict[int, tuple[str, str]]] = {}
    for ps, pair, part, alignment, exemplar in rows:
        if pair.id not in cache:
            cache[pair.id] = pair_truths(session, store, pair, exemplar, alignment, truths[exemplar.id])
        truth = cache[pair.id].get(part.index)
        if truth is None:
            continue
        correct[exemplar.id].append(float(ps.substance == truth[1]))
    return correct


def evaluate_training(session: Session) -> list[Metric]:
    out = []
    for clf in session.execute(
        sa.select(m.Classifier).where(m.Classifier.status == "ok").order_by(m.Classifier.id)
    ).scalars():
        for key, value in (clf.metrics or {}).items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                out.append(Metric("training", f"{clf.kind}:{clf.name}", key, float(value)))
    return out


@dataclass(frozen=True)
class Choice:
    """One ranked assignment as the evaluation reads it (the refinement only on rank-1 rows)."""

    name: str | None
    substance: str | None
    material_id: int | None
    refinement: dict[str, Any] | None = None


# method key -> metric -> exemplar id -> values (one per scored part, or the pair's re-render)
Scores = dict[str, dict[str, dict[int, list[float]]]]


def evaluate_inference(
    session: Session, store: BlobStore, truths: dict[int, TruthEntry], *, rerender_size: int = 128,
    rerender_spp: int = 16, rerender_max_pairs: int | None = 200, progress: Progress | None = None,
    relight_max_pairs: int | None = 200,
) -> list[Metric]:
    """Material top-1/top-5 and substance accuracy per part, re-render RMSE/SSIM per pair and the
    relighting error of pairs of the exemplar's own shape, per method."""
    return inference_metrics(inference_observations(
        session, store, truths, rerender_size=rerender_size, rerender_spp=rerender_spp,
        rerender_max_pairs=rerender_max_pairs, progress=progress, relight_max_pairs=relight_max_pairs))


def merge_scores(batches: Iterable[Scores]) -> Scores:
    """The observations of several exemplar batches as one (batches hold disjoint exemplars)."""
    merged: Scores = defaultdict(lambda: defaultdict(dict))
    for batch in batches:
        for method_key, metrics in batch.items():
            for metric, obs in metrics.items():
                for exemplar_id, values in obs.items():
                    merged[method_key][metric].setdefault(int(exemplar_id), []).extend(values)
    return {k: dict(v) for k, v in merged.items()}


def inference_observations(
    session: Session, store: BlobStore, truths: dict[int, TruthEntry], *, rerender_size: int = 128,
    rerender_spp: int = 16, rerender_max_pairs: int | None = 200, progress: Progress | None = None,
    relight_size: int = 96, relight_max_pairs: int | None = 200,
) -> Scores:
    """Every method's per-exemplar observations (the inference figures before they are pooled):
    exemplar batches can be scored apart, on other workers, and merged (`merge_scores`)."""
    rows = session.execute(
        sa.select(m.Assignment, m.Part.index, m.Material.name, m.Material.substance)
        .join(m.Part, m.Part.id == m.Assignment.part_id)
        .join(m.Pair, m.Pair.id == m.Assignment.pair_id)
        .outerjoin(m.Material, m.Material.id == m.Assignment.material_id)
        .where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)
        .order_by(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.part_id, m.Assignment.rank)
    ).all()
    ranked: dict[tuple[int, str], dict[int, list[Choice]]] = defaultdict(lambda: defaultdict(list))
    refining: set[str] = set()  # methods with refined rows: they get the `_refined` figures too
    for a, part_index, name, substance in rows:
        ranked[(a.pair_id, a.method_key)][part_index].append(
            Choice(name, substance or a.substance, a.material_id, a.refinement if a.rank == 1 else None))
        if a.refinement:
            refining.add(a.method_key)
    scores: Scores = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    relight = RelightingScores(store, relight_size, rerender_spp, relight_max_pairs)
    rerender = RerenderScores(store, rerender_size, rerender_spp, rerender_max_pairs)
    truth_cache: dict[int, dict[int, tuple[str, str]]] = {}
    for (pair_id, method_key), parts in counted(progress, "eval pairs x methods", list(ranked.items())):
        pair = session.get(m.Pair, pair_id)
        exemplar = session.get(m.Exemplar, pair.exemplar_id)
        alignment = session.execute(
            sa.select(m.Alignment).where(m.Alignment.pair_id == pair_id, m.Alignment.method == "flow-crf",
                                         m.Alignment.status == "ok")
        ).scalar_one_or_none()
        if alignment is None:
            continue
        if pair_id not in truth_cache:
            truth_cache[pair_id] = pair_truths(session, store, pair, exemplar, alignment, truths[exemplar.id])
        observed = scores[method_key]
        for part_index, choices in parts.items():
            truth = truth_cache[pair_id].get(part_index)
            if truth is None:
                continue
            names = [c.name for c in choices]
            observed["material_top1"][exemplar.id].append(float(names[:1] == [truth[0]]))
            observed["material_top5"][exemplar.id].append(float(truth[0] in names[:5]))
            if choices[0].substance is not None:
                observed["substance_accuracy"][exemplar.id].append(float(choices[0].substance == truth[1]))
        chosen = {idx: c[0].material_id for idx, c in parts.items()}
        refined = {idx: c[0].refinement for idx, c in parts.items() if c[0].refinement}
        refines = method_key in refining
        if relight.wants(session, pair, method_key, truths[exemplar.id]):
            relit = partial(relight.error, session, pair, method_key, chosen, truths[exemplar.id])
            for suffix, value in rendered_variants(relit, refined, refines).items():
                if value is not None:
                    observed[f"relight_rmse{suffix}"][exemplar.id].append(value)
        # re-render error: only pairs whose shape is the exemplar's best retrieval, to bound the cost
        if pair.exemplar_rank in (None, 1) and rerender.wants(method_key):
            rerendered = partial(rerender.error, session, pair, exemplar, method_key, chosen)
            for suffix, errors in rendered_variants(rerendered, refined, refines).items():
                if errors is not None:
                    observed[f"rerender_rmse{suffix}"][exemplar.id].append(errors[0])
                    observed[f"rerender_ssim{suffix}"][exemplar.id].append(errors[1])
    return {k: {metric: dict(obs) for metric, obs in v.items()} for k, v in scores.items()}


def ours_key(method_keys: Iterable[str]) -> str | None:
    """The newest classifier's method key ("classifier:<highest id>"): what every other method is compared with."""
    ours = {k: i for k in method_keys if method_of(k) == CLASSIFIER and (i := classifier_id_of(k)) is not None}
    return max(ours, key=ours.__getitem__, default=None)


def inference_metrics(scores: Scores) -> list[Metric]:
    """Each method's means with intervals, and each other method minus ours with a paired interval
    (metric ``<name>_vs_ours``: same exemplars resampled for both, so it says whether a gain is real)."""
    out = [estimated("inference", method_key, metric, obs)
           for method_key, metrics in sorted(scores.items()) for metric, obs in sorted(metrics.items())]
    ours = ours_key(scores)
    for method_key, metrics in sorted(scores.items()):
        if ours is None or method_key == ours:
            continue
        for metric, obs in sorted(metrics.items()):
            if metric in scores[ours]:
                est = difference_interval(obs, scores[ours][metric])
                out.append(Metric("inference", method_key, f"{metric}_vs_ours", est.value, est.count,
                                  est.low, est.high))
    return out


def _dict_metrics(stage: str, method: str, values: dict[str, Any]) -> list[Metric]:
    """A stage evaluator's numbers as Metrics; a mean it gave observations for gets their interval."""
    observations = values.get(OBSERVATIONS) or {}
    out = []
    for key, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            continue
        count_key = f"{key}_count"
        count = values.get(count_key) if isinstance(values.get(count_key), int) else None
        value = None if (isinstance(value, float) and math.isnan(value)) else float(value)
        low = high = None
        if key in observations:
            est = mean_interval(observations[key])
            low, high, count = est.low, est.high, count if count is not None else est.count
        out.append(Metric(stage, method, key, value, count, low, high))
    return out


def run_evaluation(
    groundtruth: str | Path,
    run: str | None = None,
    *,
    stages: Iterable[str] = EVAL_STAGES,
    exemplar_source: str | None = None,
    settings: Settings | None = None,
    rerender_size: int = 128,
    rerender_spp: int = 16,
    rerender_max_pairs: int | None = 200,
    on_problem: Callable[[str], None] | None = None,
    progress: Progress | None = None,
    inference_scores: Scores | None = None,
) -> tuple[str, list[Metric]]:
    """Evaluate what the database holds against a ground-truth file; stores and returns the metrics.

    Each entry left out (malformed, or naming what the database lacks) is passed to `on_problem`
    (default: a warning in the log) and the others are scored; the file is registered as the default
    for the next evaluation, and every stored figure carries its sha256. Raises ValueError when the
    file is unreadable or no entry matches an ingested exemplar. `inference_scores`: the inference
    observations scored elsewhere in exemplar batches (`evaluation_batches`, `score_batch`), used
    instead of scoring them here.
    """
    settings = settings or get_settings()
    store = default_store(settings)
    gt = read_groundtruth_file(groundtruth)
    run = run or dt.datetime.now(dt.UTC).strftime("eval-%Y%m%d-%H%M%S")
    stages = set(stages)
    metrics: list[Metric] = []
    with session_scope(settings.resolved_database_url) as session:
        matched = match_groundtruth(session, gt, exemplar_source)
        for problem in matched.problems:
            (on_problem or log.warning)(problem)
        if not matched.truths:
            raise ValueError(f"no ingested exemplar matches the ground truth in {groundtruth}"
                             f" ({len(matched.problems)} entries left out)")
        truths, records = matched.truths, matched.by_source_id()
        if "coarse-alignment" in stages:
            metrics += _dict_metrics("coarse-alignment", "hog", evaluate_coarse_alignment(session, records))
        if "fine-alignment" in stages:
            with_part_masks = {k: e for k, e in records.items() if e.part_names}
            metrics += _dict_metrics("fine-alignment", "flow-crf",
                                     evaluate_fine_alignment(session, with_part_masks, settings=settings))
        if "substances" in stages:
            metrics += evaluate_substances(session, store, truths)
        if "training" in stages:
            metrics += evaluate_training(session)
        if "inference" in stages and inference_scores is not None:  # scored in exemplar batches already
            metrics += inference_metrics(inference_scores)
        elif "inference" in stages:
            metrics += evaluate_inference(session, store, truths, rerender_size=rerender_size,
                                          rerender_spp=rerender_spp, rerender_max_pairs=rerender_max_pairs,
                                          progress=progress)
    with session_scope(settings.resolved_database_url) as session:
        params = {"groundtruth": str(groundtruth), "exemplars": len(truths), "skipped": len(matched.problems)}
        for metric in metrics:
            upsert(session, m.Evaluation, {
                "run": run, "stage": metric.stage, "method": metric.method, "metric": metric.metric,
                "value": metric.value, "count": metric.count, "ci_low": metric.low, "ci_high": metric.high,
                "params": params, "groundtruth_sha256": gt.sha256,
            }, key=["run", "stage", "method", "metric"])
        register_groundtruth(session, gt, len(truths), len(matched.problems))
    return run, metrics


def evaluation_batches(groundtruth: str | Path, batch_size: int, *, exemplar_source: str | None = None,
                       settings: Settings | None = None) -> list[list[int]]:
    """The matched exemplars' ids in batches of `batch_size`, for scoring the inference figures apart."""
    settings = settings or get_settings()
    gt = read_groundtruth_file(groundtruth)
    with session_scope(settings.resolved_database_url) as session:
        ids = sorted(match_groundtruth(session, gt, exemplar_source).truths)
    size = max(1, int(batch_size))
    return [ids[i:i + size] for i in range(0, len(ids), size)]


def score_batch(groundtruth: str | Path, exemplar_ids: Sequence[int], *, exemplar_source: str | None = None,
                settings: Settings | None = None, rerender_size: int = 128, rerender_spp: int = 16,
                rerender_max_pairs: int | None = None) -> Scores:
    """The inference observations of some matched exemplars (one batch of the evaluate flow)."""
    settings = settings or get_settings()
    store = default_store(settings)
    gt = read_groundtruth_file(groundtruth)
    wanted = {int(i) for i in exemplar_ids}
    with session_scope(settings.resolved_database_url) as session:
        truths = {k: v for k, v in match_groundtruth(session, gt, exemplar_source).truths.items() if k in wanted}
        return inference_observations(session, store, truths, rerender_size=rerender_size,
                                      rerender_spp=rerender_spp, rerender_max_pairs=rerender_max_pairs,
                                      relight_max_pairs=rerender_max_pairs)


def metrics_table(metrics: Sequence[Metric]) -> list[dict[str, Any]]:
    """Rows for a table (CLI, Prefect artifact, docs)."""
    return [
        {"stage": x.stage, "method": x.method, "metric": x.metric,
         "value": None if x.value is None else round(x.value, 4), "count": x.count,
         "95% interval": "" if x.low is None or x.high is None else f"{x.low:.3f} to {x.high:.3f}"}
        for x in metrics
    ]
