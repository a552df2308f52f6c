"""Curation: a person's verdict on a PhotoShape (the original code's result taxonomy).

A grade is keyed by what was graded: the pair, the method key and the assignment-set key of the
rank-1 materials the PhotoShape showed (`photoshapes.assignment_set_keys`), plus the grader. So a
new classifier's PhotoShape of the same pair, or the same method after re-ranking, starts
ungraded, and the earlier grade stays in the table under its own key.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.db.upsert import upsert
from photoshape_flow.profiles import DEFAULT_PUBLISH_METHOD
from photoshape_flow.publish.photoshapes import assignment_set_keys, candidate_method_keys
from photoshape_flow.vocab import GRADES


def graded_photoshape(session: Session, pair_id: int, method: str | None = None) -> tuple[str, str]:
    """(method_key, assignment-set key) of the pair's PhotoShape for `method` as it is now.

    `method` as `candidate_method_keys` takes it (``classifier``: the newest classifier's). Raises
    ValueError (one line) for an unknown pair or one without that PhotoShape.
    """
    if session.get(m.Pair, pair_id) is None:
        raise ValueError(f"pair {pair_id}: no such pair")
    found = candidate_method_keys(session, method, [pair_id])
    if not found:
        raise ValueError(f"pair {pair_id}: no PhotoShape for method {method or DEFAULT_PUBLISH_METHOD!r} "
                         "(no rank-1 assignments, or excluded)")
    method_key = found[0][1]
    return method_key, assignment_set_keys(session, [(pair_id, method_key)])[(pair_id, method_key)]


def record_grade(session: Session, pair_id: int, label: str, note: str | None = None, grader: str = "user",
                 method: str | None = None) -> int:
    """Upsert the grader's verdict on the pair's current PhotoShape of `method`; returns the Grade row id.

    Raises ValueError (one line) for an unknown label or pair, or a pair without that PhotoShape.
    """
    if label not in GRADES:
        raise ValueError(f"unknown grade {label!r}; valid grades: {', '.join(GRADES)}")
    method_key, set_key = graded_photoshape(session, pair_id, method)
    row = {"pair_id": pair_id, "method_key": method_key, "assignment_set": set_key, "label": label, "note": note,
           "grader": grader or "user"}
    return upsert(session, m.Grade, row, key=["pair_id", "method_key", "assignment_set", "grader"])[0]


def current_grades(session: Session, photoshapes: Sequence[tuple[int, str]]) -> dict[tuple[int, str], m.Grade]:
    """(pair_id, method_key) -> the newest grade given to that PhotoShape as it is now (any grader).

    A PhotoShape whose assignment set changed since it was graded, or a legacy grade without keys,
    has none here.
    """
    keys = assignment_set_keys(session, photoshapes)
    if not keys:
        return {}
    rows = session.execute(
        sa.select(m.Grade).where(m.Grade.pair_id.in_(sorted({p for p, _ in keys})),
                                 m.Grade.assignment_set.in_(sorted(set(keys.values()))))
        .order_by(m.Grade.updated_at, m.Grade.id)
    ).scalars()
    out: dict[tuple[int, str], m.Grade] = {}
    for grade in rows:  # oldest first: the newest one stays
        key = (grade.pair_id, grade.method_key or "")
        if keys.get(key) == grade.assignment_set:
            out[key] = grade
    return out
