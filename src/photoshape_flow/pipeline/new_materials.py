"""The "new materials" re-run: when materials are added, extend the training set, fine-tune, re-infer.

The set of new materials is found in the database (enabled, ok materials that the newest material
classifier does not know), never from an event's payload, so a debounced trigger after a bulk
import — or the nightly schedule — handles every material added since the last classifier.
"""

from __future__ import annotations

import logging
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.training import material_set, newest_material_classifier
from photoshape_flow.profiles import Profile, get_profile

log = logging.getLogger(__name__)


def new_material_ids(session: Session) -> list[int]:
    """Enabled, ok materials missing from the newest material classifier (all of them if none exists)."""
    current = set(material_set(session).ids)
    clf = newest_material_classifier(session)
    known = {int(i) for i in (clf.materials if clf is not None else []) if int(i) != 0}
    return sorted(current - known)


def training_render_count(session: Session) -> int:
    return int(session.execute(
        sa.select(sa.func.count()).select_from(m.Rendering).where(m.Rendering.kind == "training")
    ).scalar_one())


def run_new_materials(profile: str | Profile = "default", renders_per_material: int = 40,
                      settings: Settings | None = None) -> dict[str, Any]:
    """Render training data that includes the new materials, fine-tune the classifier, re-infer all pairs."""
    from photoshape_flow.pipeline.calibration import calibrate
    from photoshape_flow.pipeline.inference import run_inference
    from photoshape_flow.pipeline.training import run_training
    from photoshape_flow.pipeline.training_renders import run_training_renders

    settings = settings or get_settings()
    prof = get_profile(profile)
    with session_scope(settings.resolved_database_url) as session:
        new_ids = new_material_ids(session)
        existing = training_render_count(session)
        previous = newest_material_classifier(session)
        previous_id = previous.id if previous is not None else None
    if not new_ids:
        log.info("new materials: none since classifier %s", previous_id)
        return {"new_materials": [], "classifier_id": previous_id}
    renders_cfg = prof.training_renders
    target = max(existing, renders_cfg.count) + renders_per_material * len(new_ids)
    renders = run_training_renders("training", target, renders_cfg.size, renders_cfg.spp, settings)
    classifier_id = run_training(prof.training, settings=settings)
    calibrate(settings, classifier_id)
    inference = run_inference("classifier", classifier_id=classifier_id, top_k=prof.inference.top_k,
                              settings=settings)
    return {
        "new_materials": new_ids,
        "previous_classifier_id": previous_id,
        "classifier_id": classifier_id,
        "training_renders": renders,
        "inference": {"pairs": inference.pairs_done, "rows": inference.rows, "failed": len(inference.pairs_failed)},
    }
