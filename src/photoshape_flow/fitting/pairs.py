"""Which pairs `fit` works on: SQL only, so planners can list them without loading the renderer."""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.pipeline.progress import active_pairs


def fit_pairs_of(session: Session, source_key: str, pair_ids: Sequence[int] | None = None) -> list[int]:
    """Active, aligned pairs with rows of `source_key`, in id order."""
    query = active_pairs().where(
        m.Pair.id.in_(sa.select(m.Assignment.pair_id).where(m.Assignment.method_key == source_key))
    ).order_by(m.Pair.id)
    if pair_ids is not None:
        query = query.where(m.Pair.id.in_(list(pair_ids)))
    return list(session.execute(query).scalars())
