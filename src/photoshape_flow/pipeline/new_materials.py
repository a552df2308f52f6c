"""The material-added re-run: which stages to run again, and with what, when materials are added.

The set of new materials is found in the database (enabled, ok materials that the newest material
classifier does not know), never from an event's payload, so a debounced trigger after a bulk
import (or the nightly schedule) handles every material added since the last classifier.

The stages to re-run are read off the stage registry: every stage that reads `material`, or reads
what such a stage writes, in pipeline order (substances, training renders, training, inference,
publish). Each keeps its own up-to-date check, so a stage whose inputs did not change skips its
items, and publish re-renders exactly the pairs whose assignment set changed. The profile is the
one the collection was last run with (`pipeline.runs.effective_profile`); the render counts are
raised so that the new materials appear in the training data.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.pipeline.training import material_set, newest_material_classifier
from photoshape_flow.profiles import resolve_profile

log = logging.getLogger(__name__)


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


def stages_downstream_of(table: str) -> list[str]:
    """Registered stages that read `table` or read what such a stage writes, in pipeline order."""
    from photoshape_flow.stages import REGISTRY

    dirty, out = {table}, []
    for stage in REGISTRY:
        if stage.name != "ingest" and dirty & set(stage.reads):
            out.append(stage.name)
            dirty |= set(stage.writes)
    return out


@dataclass(frozen=True)
class MaterialRerun:
    """What the re-run will do: the new materials, the profile (name and `--set` overrides), the stages."""

    new_ids: list[int]
    previous_classifier_id: int | None
    profile: str
    overrides: list[str] = field(default_factory=list)
    stages: list[str] = field(default_factory=list)


def plan_material_rerun(session: Session, profile: str, overrides: Sequence[str] = (),
                        renders_per_material: int = 40) -> MaterialRerun:
    """The re-run for the materials the newest classifier lacks (no stages when there are none).

    Training and bootstrap render counts grow by `renders_per_material` per new material over what
    exists (or the profile's count, if larger), as overrides recorded with the run.
    """
    new_ids = new_material_ids(session)
    previous = newest_material_classifier(session)
    previous_id = previous.id if previous is not None else None
    if not new_ids:
        return MaterialRerun([], previous_id, profile, list(overrides))
    prof = resolve_profile(profile, list(overrides)).profile
    extra = renders_per_material * len(new_ids)
    counts = {
        "training_renders.count": max(render_count(session, "training"), prof.training_renders.count) + extra,
        "substances.bootstrap_count": max(render_count(session, "bootstrap"), prof.substances.bootstrap_count)
        + extra,
    }
    kept = [o for o in overrides if o.partition("=")[0].strip() not in counts]
    return MaterialRerun(new_ids, previous_id, profile, kept + [f"{k}={v}" for k, v in counts.items()],
                         stages_downstream_of("material"))
