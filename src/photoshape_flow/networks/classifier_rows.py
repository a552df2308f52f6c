"""Which material classifier (or substance network) a stage reads: SQL over the `classifier` table, no network loaded.

Apart from `networks.classifiers` (which loads checkpoints, and so torch) so that planners that only
need the row, such as the material-added re-run's, stay light to import.
"""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.vocab import STATUS_OK


def newest_classifier(session: Session, kind: str, with_checkpoint: bool = True) -> m.Classifier | None:
    """The newest ok network of `kind` ("material" or "substance"; highest id), with a checkpoint
    unless `with_checkpoint=False`."""
    query = sa.select(m.Classifier).where(m.Classifier.kind == kind, m.Classifier.status == STATUS_OK)
    if with_checkpoint:
        query = query.where(m.Classifier.checkpoint_blob.is_not(None))
    return session.scalars(query.order_by(m.Classifier.id.desc()).limit(1)).first()


def newest_material_classifier(session: Session, with_checkpoint: bool = True) -> m.Classifier | None:
    """The newest ok material classifier with a checkpoint, as the SQL views pick it
    (`with_checkpoint=False`: with or without one, as the stages that rank with it resolve it)."""
    return newest_classifier(session, "material", with_checkpoint)


def resolve_classifier(session: Session, classifier_id: int | None = None) -> m.Classifier | None:
    """The given material classifier, or the newest one that finished training."""
    if classifier_id is not None:
        clf = session.get(m.Classifier, classifier_id)
        if clf is None or clf.kind != "material":
            raise ValueError(f"classifier {classifier_id} is not a material classifier")
        return clf
    return newest_material_classifier(session, with_checkpoint=False)
