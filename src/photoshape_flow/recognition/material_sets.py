"""The classifier's output list: the enabled, ok materials in id order, and the hash naming the set.

SQL only (no torch), so the stages and planners that ask which materials a network should know
import it without loading the training code.
"""

from __future__ import annotations

from dataclasses import dataclass

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db.models import Material
from photoshape_flow.hashing import stable_hash
from photoshape_flow.vocab import STATUS_OK


@dataclass(frozen=True)
class MaterialSet:
    """The classifier's output list: material ids (head order, background excluded) and substances."""

    ids: tuple[int, ...]
    names: tuple[str, ...]
    substances: tuple[str, ...]
    hash: str

    @property
    def substance_of(self) -> dict[int, str]:
        return dict(zip(self.ids, self.substances, strict=True))


def material_set(session: Session) -> MaterialSet:
    """Enabled, ok materials ordered by id, with the hash that identifies the set."""
    rows = session.execute(
        sa.select(Material.id, Material.name, Material.substance)
        .where(Material.enabled.is_(True), Material.status == STATUS_OK)
        .order_by(Material.id)
    ).all()
    triples = [(int(r.id), str(r.name), str(r.substance)) for r in rows]
    return MaterialSet(
        ids=tuple(t[0] for t in triples),
        names=tuple(t[1] for t in triples),
        substances=tuple(t[2] for t in triples),
        hash=stable_hash(triples),
    )
