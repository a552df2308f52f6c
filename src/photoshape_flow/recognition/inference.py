"""Inference stage: a ranked material per part of every aligned pair, for the classifier and baselines.

For each pair with a fine alignment, each part visible in the aligned (CRF) part map is classified on
the exemplar with its mask; parts with too few pixels for the classifier are *unobserved*: their
substance is the substance network's when it saw the part, else a prior (the substances the same
part showed in the shape's other pairs, else a part-name prior), their material comes from the
method restricted to that substance, and their rows are marked `unobserved`.

Methods (`assignment.method`): `classifier` (ours: the evidence of each part ranked by the one
policy of `classify.ranking`, with the calibrations the training stage stored; rows keyed
`classifier:<id>`, so a new classifier adds rows and older ones stay queryable) and the baselines of
section 6.1 computed by the same code path: `builtin`, `no-classifier`, `color-match`. The rules of
the policy and the evidence behind each are records in docs/decisions.md. Several workers may run
this stage at once: pairs are claimed with a lease (`work_claim`), and each pair's rows are replaced
in one transaction.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import claims
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.faults import fault_point
from photoshape_flow.hashing import stable_hash
from photoshape_flow.method_keys import MethodKey
from photoshape_flow.networks.classifier_rows import resolve_classifier
from photoshape_flow.progress_sink import Progress, no_progress
from photoshape_flow.recognition.part_evidence import (
    RankingContext,
    load_part_map,
    part_inputs,
    rank_part,
)
from photoshape_flow.store import BlobStore, default_store

log = logging.getLogger(__name__)

METHODS: tuple[str, ...] = ("classifier", "no-classifier", "color-match", "builtin")
ALIGNMENT_METHOD = "flow-crf"
# No jitter at publication: the material's own scale through the texture-scale formula.
IDENTITY_UV = {"scale": 1.0, "rotation": 0.0, "offset": [0.0, 0.0]}


@dataclass
class InferenceSummary:
    method_key: str
    pairs_done: int = 0
    pairs_skipped: int = 0
    pairs_failed: list[tuple[int, str]] = field(default_factory=list)
    rows: int = 0
    blocked: list[claims.Hold] = field(default_factory=list)  # pairs another live worker holds (not skipped)


def pair_hashes(session: Session, params_hash: str, pair_ids: Sequence[int] | None = None) -> dict[int, str]:
    """The hash each aligned, non-excluded pair's rows must carry: the method's parameters and the pair's inputs.

    A pair's inputs are its alignment (`params_hash`) and its part substances (theirs), so a
    re-aligned pair or a retrained substance network makes exactly the affected rows stale, for the
    baselines as for ours.
    """
    query = (
        sa.select(m.Pair.id, m.Alignment.params_hash)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .join(m.Alignment, sa.and_(m.Alignment.pair_id == m.Pair.id, m.Alignment.method == ALIGNMENT_METHOD))
        .where(~m.Pair.exclude, ~m.Shape.exclude, ~m.Exemplar.exclude, m.Alignment.status == "ok")
        .order_by(m.Pair.id)
    )
    if pair_ids is not None:
        query = query.where(m.Pair.id.in_(list(pair_ids)))
    alignments = dict(session.execute(query).all())
    substances: dict[int, list[tuple[int, str | None]]] = {}
    rows = sa.select(m.PartSubstance.pair_id, m.PartSubstance.part_id, m.PartSubstance.params_hash)
    if pair_ids is not None:
        rows = rows.where(m.PartSubstance.pair_id.in_(list(pair_ids)))
    for pair_id, part_id, part_hash in session.execute(rows.order_by(m.PartSubstance.pair_id, m.PartSubstance.part_id)):
        substances.setdefault(pair_id, []).append((part_id, part_hash))
    return {pair_id: stable_hash({"params": params_hash, "alignment": alignment,
                                  "substances": substances.get(pair_id, [])})
            for pair_id, alignment in alignments.items()}


def pending_pairs(session: Session, method_key: str, expected: dict[int, str]) -> list[int]:
    """Pairs of `expected` (pair -> hash, `pair_hashes`) whose rows for this method are missing or stale."""
    stored = dict(session.execute(
        sa.select(m.Assignment.pair_id, m.Assignment.params_hash)
        .where(m.Assignment.method_key == method_key)
        .distinct()
    ).all())
    return [pair_id for pair_id, digest in sorted(expected.items()) if stored.get(pair_id) != digest]


def infer_pair(session: Session, ctx: RankingContext, pair: m.Pair, method_key: str, params_hash: str) -> int:
    """Replace this pair's rows for `method_key`; returns the number of rows written."""
    shape = session.get(m.Shape, pair.shape_id)
    exemplar = session.get(m.Exemplar, pair.exemplar_id)
    assert shape is not None and exemplar is not None
    parts = session.execute(sa.select(m.Part).where(m.Part.shape_id == shape.id).order_by(m.Part.index)).scalars().all()
    rows: list[m.Assignment] = []
    if ctx.method == "builtin":
        for part in parts:
            rows.append(m.Assignment(
                pair_id=pair.id, part_id=part.id, method="builtin", method_key=method_key, rank=1,
                material_id=None, score=None, params={"builtin": part.builtin_material}, params_hash=params_hash,
            ))
    else:
        alignment = session.execute(
            sa.select(m.Alignment).where(m.Alignment.pair_id == pair.id, m.Alignment.method == ALIGNMENT_METHOD)
        ).scalar_one()
        image = ctx.store.load_image(exemplar.image_blob)[..., :3]
        fg = ctx.store.load_image(exemplar.mask_blob) > 0 if exemplar.mask_blob else np.ones(image.shape[:2], bool)
        if fg.ndim == 3:
            fg = fg[..., 0]
        part_map = load_part_map(ctx.store, alignment, image.shape[:2])
        items = part_inputs(session, ctx, pair.id, parts, part_map)
        batch: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        if ctx.method == "classifier":
            assert ctx.model is not None
            masks = [it.mask if it.mask is not None else fg for it in items]
            mat, sub = ctx.model.predict(image, masks)
            batch = {it.part.id: (mat[i], sub[i]) for i, it in enumerate(items)}
        for item in items:
            ranked = rank_part(ctx, image, fg, item, pair.id, batch)
            for rank, r in enumerate(ranked, start=1):
                rows.append(m.Assignment(
                    pair_id=pair.id, part_id=item.part.id, method=ctx.method, method_key=method_key,
                    classifier_id=ctx.classifier.id if ctx.method == "classifier" and ctx.classifier else None,
                    rank=rank, material_id=r.material_id, score=r.score, posterior=r.posterior,
                    substance=r.substance,
                    unobserved=item.mask is None,
                    params={"part_substance": item.substance.substance,
                            "substance_confidence": item.substance.probs.get(item.substance.substance or "", None),
                            "uv": IDENTITY_UV,
                            **({"color_likelihood": round(item.color[r.material_id], 6)} if item.color else {}),
                            **({} if item.head else {"classifier_head": False})},
                    params_hash=params_hash,
                ))
    session.execute(sa.delete(m.Assignment).where(m.Assignment.pair_id == pair.id,
                                                  m.Assignment.method_key == method_key))
    session.add_all(rows)
    return len(rows)


def run_inference(
    method: str = "classifier",
    *,
    classifier_id: int | None = None,
    pair_ids: Sequence[int] | None = None,
    top_k: int = 5,
    batch_size: int = 16,
    settings: Settings | None = None,
    color_prior: bool = True,
    calibrate_substances: bool = True,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> InferenceSummary:
    """Write ranked assignments for every pending pair with one method; resumable and idempotent.

    `color_prior` (classifier only) multiplies the ranking by the colour likelihood of
    `classify.color_prior`; `calibrate_substances` tempers the substance confidence with its
    network's part-level temperature (`classify.substance_calibration`). Both off, the ranking is
    the paper's (probability x substance confidence).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    settings = settings or get_settings()
    store = store if store is not None else default_store(settings)
    url = settings.resolved_database_url
    with session_scope(url) as session:
        classifier = resolve_classifier(session, classifier_id) if method == "classifier" else None
        ctx = RankingContext(session, store, method, classifier, settings, top_k, color_prior, calibrate_substances)
        method_key = str(MethodKey.for_classifier(classifier.id) if classifier is not None else MethodKey(method))
        expected = pair_hashes(session, stable_hash(ctx.params), pair_ids)
        todo = pending_pairs(session, method_key, expected)
    summary = InferenceSummary(method_key=method_key)
    stage = f"inference:{method_key}"
    report = progress or no_progress

    def tick() -> None:
        handled = summary.pairs_done + summary.pairs_skipped + len(summary.pairs_failed)
        report(f"inference {method_key} pairs", handled, len(todo))

    tick()
    for start in range(0, len(todo), batch_size):
        keys = [str(p) for p in todo[start : start + batch_size]]
        with session_scope(url) as session:
            mine: list[str] = []
            for key in keys:  # one claim per pair: each pair's rows carry their own hash
                mine += claims.claim(session, stage, [key], params_hash=expected[int(key)],
                                     lease_seconds=settings.claim_lease_seconds, retry_failed=True)
            held = claims.live_holds(session, stage, [k for k in keys if k not in mine])
        summary.blocked += held
        summary.pairs_skipped += len(keys) - len(mine) - sum(h.count for h in held)
        tick()
        for key in mine:
            pair_id = int(key)
            try:
                with session_scope(url) as session:
                    pair = session.get(m.Pair, pair_id)
                    assert pair is not None
                    summary.rows += infer_pair(session, ctx, pair, method_key, expected[pair_id])
                    claims.complete(session, stage, [key])
                summary.pairs_done += 1
                fault_point("inference-pair-done")
            except Exception as exc:  # one bad pair never stops the batch
                reason = f"{type(exc).__name__}: {exc}"
                log.warning("pair %s: %s inference failed: %s", pair_id, method_key, reason)
                summary.pairs_failed.append((pair_id, reason))
                with session_scope(url) as session:
                    claims.fail(session, stage, key, reason)
            tick()
    log.info("inference %s: %d pairs, %d rows, %d failed", method_key, summary.pairs_done, summary.rows,
             len(summary.pairs_failed))
    return summary


def run_all_methods(
    methods: Iterable[str] = METHODS, settings: Settings | None = None, **kwargs: Any
) -> list[InferenceSummary]:
    """Ours and every baseline; the classifier is skipped (with a log line) when none is trained."""
    out = []
    for method in methods:
        if method == "classifier":
            with session_scope((settings or get_settings()).resolved_database_url) as session:
                if resolve_classifier(session, kwargs.get("classifier_id")) is None:
                    log.warning("inference: no trained material classifier yet; skipping method 'classifier'")
                    continue
        out.append(run_inference(method, settings=settings, **kwargs))
    return out
