"""Per-stage progress (done / pending / failed / rejected) computed from the rows each stage records.

One counter per stage; the stage registry (`photoshape_flow.stages`) names each stage's counter and
`stages.stage_progress` runs them in pipeline order. `rejected` counts input the stage refused on
purpose (a malformed file, a render its quality check discarded); `failed` counts errors and crashes,
which a re-run retries. Where a count depends on the profile (publish: pairs up to `publish.max_rank`),
it assumes the profile of the newest recorded run (`assumed_profile`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.pipeline.runs import last_run, run_profile
from photoshape_flow.profiles import ResolvedProfile, resolve_profile
from photoshape_flow.vocab import STATUS_OK, STATUS_REJECTED

# the `descriptor` of every feature row coarse alignment writes (`HogParams.name`: hog-<channels>)
COARSE_DESCRIPTOR_PREFIX = "hog-"


@dataclass(frozen=True)
class StageProgress:
    stage: str
    unit: str
    done: int
    pending: int
    failed: int
    rejected: int = 0


@dataclass(frozen=True)
class AssumedProfile:
    """The profile progress counts assume: the newest recorded run's, else the default profile."""

    resolved: ResolvedProfile
    run_id: int | None  # the `pipeline_run` it came from; None: no run recorded (the default profile)

    def describe(self) -> str:
        overrides = "".join(f" --set {k}={v}" for k, v in self.resolved.overrides)
        source = f"last run #{self.run_id}" if self.run_id is not None else "no run recorded yet"
        return (f"profile {self.resolved.name}{overrides} ({source}; publish: pairs up to rank "
                f"{self.resolved.profile.publish.max_rank})")


def assumed_profile(session: Session) -> AssumedProfile:
    row = last_run(session)
    if row is None:
        return AssumedProfile(resolve_profile("default"), None)
    return AssumedProfile(run_profile(row), int(row.id))


def _count(session: Session, query: sa.Select) -> int:
    return int(session.execute(sa.select(sa.func.count()).select_from(query.subquery())).scalar_one())


def active_pairs() -> sa.Select:
    """Pairs most stages work on: no exclusion on the pair, its shape or its exemplar."""
    return (
        sa.select(m.Pair.id)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .where(~m.Pair.exclude, ~m.Shape.exclude, ~m.Exemplar.exclude)
    )


def _aligned_ok() -> sa.Select:
    return sa.select(m.Alignment.pair_id).where(m.Alignment.status == "ok")


def _with_substance() -> sa.Select:
    return sa.select(m.PartSubstance.pair_id)


def _inferred() -> sa.Select:
    return sa.select(m.Assignment.pair_id).where(m.Assignment.method == "classifier")


def _by_outcome(session: Session, query: sa.Select, status: sa.ColumnElement) -> tuple[int, int, int]:
    """(ok, failed, rejected) rows of `query`: failed is every status but ok and rejected."""
    return (
        _count(session, query.where(status == STATUS_OK)),
        _count(session, query.where(status.not_in((STATUS_OK, STATUS_REJECTED)))),
        _count(session, query.where(status == STATUS_REJECTED)),
    )


def ingest_progress(session: Session) -> StageProgress:
    ok_items = failed_items = rejected_items = 0
    for model in (m.Shape, m.Exemplar, m.Material, m.Envmap):
        ok, failed, rejected = _by_outcome(session, sa.select(model.id), model.status)
        ok_items, failed_items, rejected_items = ok_items + ok, failed_items + failed, rejected_items + rejected
    return StageProgress("ingest", "items", ok_items, 0, failed_items, rejected_items)


def coarse_alignment_progress(session: Session) -> StageProgress:
    # only the descriptors coarse alignment writes: ingest records `dedupe-hog` for every exemplar
    view_features = sa.select(m.ViewFeature.shape_id).where(
        m.ViewFeature.descriptor.startswith(COARSE_DESCRIPTOR_PREFIX)
    )
    ex_features = sa.select(m.ExemplarFeature.exemplar_id).where(
        m.ExemplarFeature.descriptor.startswith(COARSE_DESCRIPTOR_PREFIX)
    )
    shapes_ok = sa.select(m.Shape.id).where(m.Shape.status == "ok", ~m.Shape.exclude)
    shapes_done = view_features.where(m.ViewFeature.status == "ok")
    shapes_failed = view_features.where(m.ViewFeature.status != "ok")
    exemplars_ok = sa.select(m.Exemplar.id).where(m.Exemplar.status == "ok", ~m.Exemplar.exclude)
    ex_done = ex_features.where(m.ExemplarFeature.status == "ok")
    ex_failed = ex_features.where(m.ExemplarFeature.status != "ok")
    done = _count(session, shapes_ok.where(m.Shape.id.in_(shapes_done))) + _count(
        session, exemplars_ok.where(m.Exemplar.id.in_(ex_done))
    )
    failed = _count(session, shapes_ok.where(m.Shape.id.in_(shapes_failed))) + _count(
        session, exemplars_ok.where(m.Exemplar.id.in_(ex_failed))
    )
    total = _count(session, shapes_ok) + _count(session, exemplars_ok)
    return StageProgress("coarse-alignment", "shapes+exemplars", done, max(total - done - failed, 0), failed)


def fine_alignment_progress(session: Session) -> StageProgress:
    pairs = active_pairs()
    aligned_failed = sa.select(m.Alignment.pair_id).where(m.Alignment.status != "ok")
    n_pairs = _count(session, pairs)
    done = _count(session, pairs.where(m.Pair.id.in_(_aligned_ok())))
    failed = _count(session, pairs.where(m.Pair.id.in_(aligned_failed), m.Pair.id.not_in(_aligned_ok())))
    return StageProgress("fine-alignment", "pairs", done, n_pairs - done - failed, failed)


def _pairs_progress(session: Session, stage: str, done: sa.Select, ready: sa.Select) -> StageProgress:
    """Active pairs with a row in `done`, and those `ready` for the stage (inputs there) without one."""
    pairs = active_pairs()
    finished = _count(session, pairs.where(m.Pair.id.in_(done)))
    pending = _count(session, pairs.where(m.Pair.id.in_(ready), m.Pair.id.not_in(done)))
    return StageProgress(stage, "pairs", finished, pending, 0)


def substances_progress(session: Session) -> StageProgress:
    return _pairs_progress(session, "substances", _with_substance(), _aligned_ok())


def training_renders_progress(session: Session) -> StageProgress:
    """The training round's renders only: the bootstrap round's are the substances stage's
    (`rendering_progress` counts every kind under the stage that made it)."""
    renders = sa.select(m.Rendering.id).where(m.Rendering.kind == "training")
    ok, failed, rejected = _by_outcome(session, renders, m.Rendering.status)
    return StageProgress("training-renders", "renderings", ok, 0, failed, rejected)


# the stage that makes each kind of rendering (`vocab.RENDERING_KINDS`)
RENDERING_STAGE = {
    "preview": "ingest", "part-map": "fine-alignment", "bootstrap": "substances", "training": "training-renders",
    "photoshape": "publish", "builtin": "publish", "exemplar-gt": "demo",
}
REASON_EXAMPLES = 3  # rejection reasons listed per kind of rendering (the most frequent)


@dataclass(frozen=True)
class RenderingProgress:
    """One kind of rendering: the stage that made it, its rows by outcome, and why renders were rejected
    (`reasons`: (reason, count, one full message), most frequent first)."""

    kind: str
    stage: str
    ok: int
    failed: int
    rejected: int
    reasons: list[tuple[str, int, str]] = field(default_factory=list)

    def reasons_text(self) -> str:
        """"3 saturated fraction (e.g. saturated fraction 0.688 > 0.05)", joined by "; "."""
        return "; ".join(f"{n} {reason} (e.g. {example})" if example != reason else f"{n} {reason}"
                         for reason, n, example in self.reasons)


def rejection_reason(error: str | None) -> str:
    """A rejection message without its numbers, so rejections of one cause group together:
    "saturated fraction 0.688 > 0.05" -> "saturated fraction"."""
    text = (error or "no reason recorded").strip()
    head = re.split(r"\s*[-+]?\d", text, maxsplit=1)[0].strip(" :,;=(")
    return head or text


def rendering_progress(session: Session) -> list[RenderingProgress]:
    """Every kind of rendering recorded, under the stage that made it, with rejection reasons summarised."""
    counts: dict[str, dict[str, int]] = {}
    for kind, status, n in session.execute(
        sa.select(m.Rendering.kind, m.Rendering.status, sa.func.count()).group_by(m.Rendering.kind, m.Rendering.status)
    ):
        counts.setdefault(str(kind), {})[str(status)] = int(n)
    reasons: dict[str, dict[str, list]] = {}
    for kind, error, n in session.execute(
        sa.select(m.Rendering.kind, m.Rendering.error, sa.func.count())
        .where(m.Rendering.status == STATUS_REJECTED).group_by(m.Rendering.kind, m.Rendering.error)
    ):
        entry = reasons.setdefault(str(kind), {}).setdefault(rejection_reason(error), [0, error or ""])
        entry[0] += int(n)
    order = {kind: i for i, kind in enumerate(RENDERING_STAGE)}
    out = []
    for kind in sorted(counts, key=lambda k: (order.get(k, len(order)), k)):
        by_status = counts[kind]
        ok, rejected = by_status.get(STATUS_OK, 0), by_status.get(STATUS_REJECTED, 0)
        top = sorted(reasons.get(kind, {}).items(), key=lambda item: (-item[1][0], item[0]))[:REASON_EXAMPLES]
        out.append(RenderingProgress(kind, RENDERING_STAGE.get(kind, kind), ok,
                                     sum(by_status.values()) - ok - rejected, rejected,
                                     [(reason, n, example or reason) for reason, (n, example) in top]))
    return out


def training_progress(session: Session) -> StageProgress:
    classifiers = sa.select(m.Classifier.id)
    return StageProgress(
        "training",
        "classifiers",
        _count(session, classifiers.where(m.Classifier.status == "ok")),
        _count(session, classifiers.where(m.Classifier.status == "training")),
        _count(session, classifiers.where(m.Classifier.status == "failed")),
    )


def inference_progress(session: Session) -> StageProgress:
    return _pairs_progress(session, "inference", _inferred(), _with_substance())


def fit_progress(session: Session) -> StageProgress:
    """Pairs with `fit` rows; pending: pairs the classifier ranked without them."""
    fitted = sa.select(m.Assignment.pair_id).where(m.Assignment.method == "fit")
    return _pairs_progress(session, "fit", fitted, _inferred())


def publish_progress(session: Session) -> StageProgress:
    """Published pairs; pending: inferred pairs up to the assumed profile's `publish.max_rank` not yet tried."""
    pairs = active_pairs()
    published = sa.select(m.Rendering.pair_id).where(m.Rendering.kind == "photoshape", m.Rendering.status == "ok")
    publish_failed = sa.select(m.Rendering.pair_id).where(
        m.Rendering.kind == "photoshape", m.Rendering.status != "ok"
    )
    max_rank = assumed_profile(session).resolved.profile.publish.max_rank
    done = _count(session, pairs.where(m.Pair.id.in_(published)))
    failed = _count(session, pairs.where(m.Pair.id.in_(publish_failed), m.Pair.id.not_in(published)))
    pending = _count(session, pairs.where(
        m.Pair.rank <= max_rank, m.Pair.id.in_(_inferred()), m.Pair.id.not_in(published),
        m.Pair.id.not_in(publish_failed),
    ))
    return StageProgress("publish", "pairs", done, pending, failed)


def table_counts(session: Session) -> dict[str, dict[str, int]]:
    """Rows per table, split by status where the table has one."""
    result: dict[str, dict[str, int]] = {}
    for model in m.ALL_TABLES:
        table = model.__table__
        if "status" in table.c:
            rows = session.execute(sa.select(table.c.status, sa.func.count()).group_by(table.c.status)).all()
            counts = {str(status): int(n) for status, n in rows}
        else:
            counts = {"rows": int(session.execute(sa.select(sa.func.count()).select_from(table)).scalar_one())}
        result[table.name] = counts
    return result
