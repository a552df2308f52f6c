"""The material-added re-run: which stages to run again, and with what, when materials are added.

The set of new materials is found in the database (enabled, ok materials that the newest material
classifier does not know), never from an event's payload, so a debounced trigger after a bulk
import (or the nightly schedule) handles every material added since the last classifier.

The stages to re-run are read off the stage registry (`rerun_stages`, D36): the triggered run fits
first, in minutes: every stage downstream of `material` except the retraining ones (substances,
training renders, training, inference), so `fit` (limited to the pairs whose candidate set the new
materials join, `affected_pairs`) then `publish` of those pairs and the gallery. A new material can
win a part without a retrain; retraining waits for the nightly run, which runs the full chain. Each
stage keeps its own up-to-date check, and publish re-renders exactly the pairs whose assignment set
(of `publish.method`) changed. The profile is the one the collection was last run with
(`pipeline.runs.effective_profile`); the render counts are raised, for the nightly retraining, so
that the new materials appear in the training data.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.fitting.pairs import fit_pairs_of
from photoshape_flow.method_keys import MethodKey
from photoshape_flow.networks.classifier_rows import newest_material_classifier, resolve_classifier
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.recognition.material_sets import material_set

log = logging.getLogger(__name__)

Trigger = Literal["triggered", "nightly"]  # the material-added automation, or the nightly full chain


def new_material_ids(session: Session) -> list[int]:
    """Enabled, ok materials missing from the newest material classifier (all of them if none exists)."""
    current = set(material_set(session).ids)
    clf = newest_material_classifier(session)
    known = {int(i) for i in (clf.materials if clf is not None else []) if int(i) != 0}
    return sorted(current - known)


def render_count(session: Session, kind: str) -> int:
    return int(session.execute(
        sa.select(sa.func.count()).select_from(m.Rendering).where(m.Rendering.kind == kind)
    ).scalar_one())


class StageLike(Protocol):
    """What the planner reads of a registered stage (`stages.registry.Stage`)."""

    name: str
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    retraining: bool


def rerun_stages(registry: Sequence[StageLike], table: str, trigger: Trigger) -> list[str]:
    """The stages a change to `table` re-runs, in registry order.

    ``nightly``: every stage that reads `table` or reads what such a stage writes, retraining included
    (substances, training renders, training, inference, fit, publish for `material`). ``triggered``
    (the material-added automation): the same walk, but a retraining stage is neither run nor taken
    to have changed what it writes, so the chain is what needs no new network: for `material`,
    `fit` (whose candidates hold every material the classifier was not trained on) then `publish`.
    """
    dirty, out = {table}, []
    for stage in registry:
        if stage.name == "ingest" or not dirty & set(stage.reads):
            continue
        if stage.retraining and trigger == "triggered":
            continue
        out.append(stage.name)
        dirty |= set(stage.writes)
    return out


def affected_pairs(session: Session) -> tuple[str | None, list[int]]:
    """(fit's method key, the pairs it re-fits when materials are added): the newest classifier's active
    pairs with at least one observed part.

    Every enabled material the classifier was not trained on joins the candidates of every observed
    part (`fit.candidates`), so these are exactly the pairs whose candidate set the new materials
    join; a pair with no observed part keeps the classifier's ranking and is left alone.
    """
    classifier = resolve_classifier(session)
    if classifier is None:
        return None, []
    source = str(MethodKey.for_classifier(classifier.id))
    observed = set(session.execute(
        sa.select(m.Assignment.pair_id).where(m.Assignment.method_key == source, m.Assignment.rank == 1,
                                              ~m.Assignment.unobserved)
    ).scalars())
    return str(MethodKey.fit_of(classifier.id)), [p for p in fit_pairs_of(session, source) if p in observed]


@dataclass(frozen=True)
class MaterialRerun:
    """What the triggered re-run will do: the new materials, the profile (name and `--set` overrides),
    the stages, the pairs they are limited to, and the fit rows whose changes it reports."""

    new_ids: list[int]
    previous_classifier_id: int | None
    profile: str
    overrides: list[str] = field(default_factory=list)
    stages: list[str] = field(default_factory=list)
    pairs: list[int] = field(default_factory=list)  # items of every stage in `stages` (all are per pair)
    fit_key: str | None = None  # `fit:<classifier id>`: the rows the run's changed-parts counts compare
    new_names: list[str] = field(default_factory=list)  # the new materials' names (`new_ids` order), for people


def plan_material_rerun(session: Session, profile: str, overrides: Sequence[str] = (),
                        renders_per_material: int = 40, *, registry: Sequence[StageLike]) -> MaterialRerun:
    """The triggered re-run for the materials the newest classifier lacks (no stages when there are none).

    Its stages are `rerun_stages(registry, ..., "triggered")`, limited to `affected_pairs`; the caller
    (the CLI, flows/) passes the stage registry, which sits above pipeline/. Training and
    bootstrap render counts grow by `renders_per_material` per new material over what exists (or the
    profile's count, if larger), as overrides recorded with the run: the triggered run does not use
    them, the nightly run does (it runs with the profile and overrides the collection was last run
    with), so it retrains with the new materials in its training data.
    """
    new_ids = new_material_ids(session)
    previous = newest_material_classifier(session)
    previous_id = previous.id if previous is not None else None
    if not new_ids:
        return MaterialRerun([], previous_id, profile, list(overrides))
    names = dict(session.execute(sa.select(m.Material.id, m.Material.name).where(m.Material.id.in_(new_ids))).all())
    prof = resolve_profile(profile, list(overrides)).profile
    extra = renders_per_material * len(new_ids)
    counts = {
        "training_renders.count": max(render_count(session, "training"), prof.training_renders.count) + extra,
        "substances.bootstrap_count": max(render_count(session, "bootstrap"), prof.substances.bootstrap_count)
        + extra,
    }
    kept = [o for o in overrides if o.partition("=")[0].strip() not in counts]
    fit_key, pairs = affected_pairs(session)
    return MaterialRerun(new_ids, previous_id, profile, kept + [f"{k}={v}" for k, v in counts.items()],
                         rerun_stages(registry, "material", "triggered"), pairs, fit_key,
                         [str(names.get(i, i)) for i in new_ids])
