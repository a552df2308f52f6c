"""Batches of item IDs for the stages that fan out, and claimed processing of one batch.

The Prefect flows map a task over `plan(...)`'s batches; each task calls `process(...)`, which claims
its items in `work_claim` (so several workers or Dask processes never do an item twice, and a killed
worker's items are re-claimed once its lease expires), runs the stage function on the items it won
and marks them done. Stage functions are idempotent on their own, so a claim is about not wasting
work and not racing on the same rows, never about correctness of the stored results.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import claims
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.runner import Profile, get_profile, publish_pair_ids

BATCHED_STAGES: tuple[str, ...] = ("coarse-alignment", "fine-alignment", "inference", "publish")


def _batches(ids: Sequence[int], size: int) -> list[list[int]]:
    return [list(ids[i : i + size]) for i in range(0, len(ids), size)]


def _active_pairs(session: sa.orm.Session) -> list[int]:
    return list(session.execute(
        sa.select(m.Pair.id)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .where(~m.Pair.exclude, ~m.Shape.exclude, ~m.Exemplar.exclude)
        .order_by(m.Pair.id)
    ).scalars())


def plan(stage: str, profile: str | Profile = "default", settings: Settings | None = None,
         batch_size: int = 32, part: str | None = None) -> list[list[int]]:
    """Batches of the IDs a stage works on (shapes or exemplars for `part` of coarse alignment, else pairs)."""
    settings = settings or get_settings()
    prof = get_profile(profile)
    with session_scope(settings.resolved_database_url) as session:
        if stage == "coarse-alignment":
            model = m.Exemplar if part == "exemplars" else m.Shape
            ids = list(session.execute(
                sa.select(model.id).where(model.status == "ok", ~model.exclude).order_by(model.id)
            ).scalars())
        elif stage in ("fine-alignment", "inference"):
            ids = _active_pairs(session)
        elif stage == "publish":
            ids = publish_pair_ids(settings, prof.publish_max_rank)
        else:
            raise ValueError(f"stage {stage!r} does not fan out; run it whole")
    return _batches(ids, batch_size)


def params_hash(stage: str, profile: Profile, part: str | None = None) -> str:
    payload = {"stage": stage, "part": part, "profile": profile.to_dict()}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def process(stage: str, ids: Sequence[int], profile: str | Profile = "default", settings: Settings | None = None,
            part: str | None = None, method: str | None = None) -> dict[str, Any]:
    """Claim `ids` for `stage`, run the stage on those this worker won, mark them done."""
    settings = settings or get_settings()
    prof = get_profile(profile)
    if stage == "inference":  # run_inference claims its pairs itself (per method and classifier)
        from photoshape_flow.pipeline.inference import run_inference

        result = run_inference(method or "classifier", pair_ids=ids, top_k=prof.top_k, settings=settings)
        claimed = result.pairs_done + len(result.pairs_failed)
        from photoshape_flow.pipeline.runner import _summary

        return {"requested": len(ids), "claimed": claimed, "result": _summary(result)}
    claim_stage = f"{stage}:{part or 'items'}"
    digest = params_hash(stage, prof, part)
    with session_scope(settings.resolved_database_url) as session:
        won = claims.claim(session, claim_stage, [str(i) for i in ids], params_hash=digest,
                           lease_seconds=settings.claim_lease_seconds, retry_failed=True)
    mine = [int(k) for k in won]
    summary: dict[str, Any] = {"requested": len(ids), "claimed": len(mine)}
    if not mine:
        return summary
    try:
        summary["result"] = _run(stage, mine, prof, settings, part)
    except Exception as exc:
        with session_scope(settings.resolved_database_url) as session:
            for key in won:
                claims.fail(session, claim_stage, key, f"{type(exc).__name__}: {exc}")
        raise
    with session_scope(settings.resolved_database_url) as session:
        claims.complete(session, claim_stage, won)
    return summary


def _run(stage: str, ids: list[int], profile: Profile, settings: Settings, part: str | None) -> Any:
    from photoshape_flow.pipeline import runner

    if stage == "coarse-alignment":
        from photoshape_flow.pipeline.coarse_alignment import (
            CoarseConfig,
            compute_exemplar_features,
            compute_view_features,
        )

        config = CoarseConfig(exemplar_topk=profile.exemplar_topk, shape_topn=profile.shape_topn)
        if part == "exemplars":
            return compute_exemplar_features(ids, config=config, settings=settings)
        return compute_view_features(ids, config=config, settings=settings)
    if stage == "fine-alignment":
        return runner.run_fine(settings, profile, pair_ids=ids)
    if stage == "publish":
        from photoshape_flow.pipeline.publish import run_publish

        result = run_publish(ids, None, settings, views=profile.publish_views, size=profile.publish_size,
                             spp=profile.publish_spp, formats=profile.publish_formats)
        return runner._summary(result)
    raise ValueError(f"stage {stage!r} does not fan out")
