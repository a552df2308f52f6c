"""Which material classifier a stage reads: SQL over the `classifier` table, no network loaded.

Apart from `networks.classifiers` (which loads checkpoints, and so torch) so that planners that only
need the row, such as the material-added re-run's, stay light to import.
"""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.vocab import STATUS_OK


def newest_material_classifier(session: Session, with_checkpoint: bool = True) -> m.Classifier | None:
    """The newest ok material classifier (highest id) with a checkpoint, as the SQL views pick it
    (`with_checkpoint=False`: with or without one, as the stages that rank with it resolve it)."""
    query = sa.select(m.Classifier).where(m.Classifier.kind == "material", m.Classifier.status == STATUS_OK)
    if with_checkpoint:
        query = query.where(m.Classifier.checkpoint_blob.is_not(None))
    return session.scalars(query.order_by(m.Classifier.id.desc()).limit(1)).first()


def resolve_classifier(session: Session, classifier_id: int | None = None) -> m.Classifier | None:
    """The given material classifier, or the newest one that finished training."""
    if classifier_id is not None:
        clf = session.get(m.Classifier, classifier_id)
        if clf is None or clf.kind != "material":
            raise ValueError(f"classifier {classifier_id} is not a material classifier")
        return clf
    return newest_material_classifier(session, with_checkpoint=False)
