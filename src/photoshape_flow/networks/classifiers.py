"""Which trained network a later stage reads, and loading it: the newest ok material classifier, a
given one, the substance networks whose part substances weight the ranking, and their checkpoints."""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.infer import load_classifier
from photoshape_flow.classify.substance_train import checkpoint_from_bytes, load_model
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.devices import resolve_device
from photoshape_flow.networks.calibrations import Calibration
from photoshape_flow.networks.classifier_rows import newest_material_classifier
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_OK


def substance_networks(session: Session) -> list[int]:
    """The substance networks whose part substances weight the ranking."""
    return sorted(int(n) for n in session.execute(
        sa.select(m.PartSubstance.classifier_id).where(m.PartSubstance.classifier_id.is_not(None)).distinct()
    ).scalars())


def load_material_classifier(
    classifier_id: int | None = None, settings: Settings | None = None, device: str | None = None,
    kind: str = "material", store: BlobStore | None = None,
) -> tuple[m.Classifier, Any]:
    """(row, `MaterialClassifier`) for `classifier_id` or the newest ok material classifier.

    The model reads photos with the BatchNorm prior chosen for it (`Calibration.bn_prior`), if any.
    ``kind="substance"`` loads the substances stage's part recogniser (same network family) by id.
    """
    settings = settings or get_settings()
    with session_scope(settings.resolved_database_url) as session:
        if classifier_id is None:
            row = newest_material_classifier(session)
            if row is None:
                raise LookupError("no trained material classifier (status ok); run the training stage first")
        else:
            row = session.get(m.Classifier, classifier_id)
            if row is None or row.kind != kind:
                raise LookupError(f"classifier {classifier_id}: no such {kind} classifier")
            if row.status != STATUS_OK or not row.checkpoint_blob:
                raise LookupError(f"classifier {classifier_id}: status {row.status}, not usable")
        session.expunge(row)
    store = store if store is not None else default_store(settings)
    return row, load_classifier(store.read_bytes(row.checkpoint_blob), device=device or settings.device,
                                bn_prior=Calibration.of(row).bn_prior)


def load_substance_network(row: Any, store: BlobStore, device: str) -> Any:
    """The network of a substance row: the segmentation net, or the part recogniser (`MaterialClassifier`)."""
    data = store.read_bytes(row.checkpoint_blob)
    if (row.config or {}).get("arch", "unet") != "unet":
        return load_classifier(data, device=device)
    return load_model(checkpoint_from_bytes(data), resolve_device(device))
