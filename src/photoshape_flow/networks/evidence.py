"""The evidence of a stored classifier, as every ranker builds it (inference, the posterior's reliability,
the fit's calibration, `photoshape retrieve`): the row's policy and its calibrated colour likelihood."""

from __future__ import annotations

from collections.abc import Collection
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.classify.evidence import ClassifierEvidence
from photoshape_flow.db import models as m
from photoshape_flow.networks.calibrations import stored_color_prior
from photoshape_flow.store import BlobStore


def stored_evidence(session: Session, store: BlobStore, classifier: m.Classifier, model: Any, *,
                    enabled: Collection[int] | None = None, color: bool = True) -> ClassifierEvidence:
    """`ClassifierEvidence.for_classifier` of `model` (the row `classifier`'s network) with the stored colour
    sigma (`color=False`, or none stored: no colour likelihood); `enabled`: the materials that may be ranked."""
    prior = stored_color_prior(session, store, model.materials, classifier) if color else None
    return ClassifierEvidence.for_classifier(model, classifier.config, enabled=enabled, color_prior=prior)
