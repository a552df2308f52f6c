"""Curation: a person's verdict on a PhotoShape (the original code's result taxonomy)."""

from __future__ import annotations

from sqlalchemy.orm import Session

from photoshape_flow.db import models as m


def record_grade(session: Session, pair_id: int, label: str, note: str | None = None, grader: str = "user") -> int:
    """Upsert the grader's verdict on a PhotoShape; returns the Grade row id.

    Raises ValueError (one line) for an unknown label or pair.
    """
    from photoshape_flow.db.upsert import upsert
    from photoshape_flow.vocab import GRADES

    if label not in GRADES:
        raise ValueError(f"unknown grade {label!r}; valid grades: {', '.join(GRADES)}")
    if session.get(m.Pair, pair_id) is None:
        raise ValueError(f"pair {pair_id}: no such pair")
    row = {"pair_id": pair_id, "label": label, "note": note, "grader": grader or "user"}
    return upsert(session, m.Grade, row, key=["pair_id", "grader"])[0]
