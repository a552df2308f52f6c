"""What a fit run changed, part by part: the numbers the material-added re-run reports.

The re-run snapshots the `fit` rows of the pairs it re-fits before and after (`fit_snapshot`) and
compares them (`fit_changes`, pure): how many parts' candidate sets the new materials joined, how
many parts' first material changed, how many parts a new material now wins. Read off the rows, so
the CLI and the Prefect flow report the same figures whichever process did the fitting, and a pair
skipped as up to date changes nothing.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m

PartKey = tuple[int, int]  # (pair id, part id)


@dataclass(frozen=True)
class PartFit:
    """One part's fit rows: its first material and every material ranked (its candidate set)."""

    first: int | None
    candidates: frozenset[int]


@dataclass(frozen=True)
class FitChanges:
    """Parts of the re-fitted pairs: looked at, whose candidate set grew, whose winner changed, won by new."""

    parts: int = 0
    grown: int = 0  # a new material joined the part's candidate set
    changed: int = 0  # first material differs from before the run (a part fitted for the first time counts)
    won_by_new: int = 0  # first material is one of the new materials

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def fit_changes(before: Mapping[PartKey, PartFit], after: Mapping[PartKey, PartFit],
                new_ids: Collection[int]) -> FitChanges:
    """Compare two snapshots of the same pairs' fit rows (see the module docstring)."""
    new = set(new_ids)
    grown = changed = won = 0
    for key, now in after.items():
        was = before.get(key, PartFit(None, frozenset()))
        grown += bool((now.candidates & new) - was.candidates)
        changed += now.first != was.first
        won += now.first in new
    return FitChanges(len(after), grown, changed, won)


def fit_snapshot(session: Session, method_key: str | None, pair_ids: Sequence[int]) -> dict[PartKey, PartFit]:
    """(pair, part) -> `PartFit` of the `method_key` rows of `pair_ids` (empty without a key)."""
    if method_key is None or not pair_ids:
        return {}
    first: dict[PartKey, int | None] = {}
    ranked: dict[PartKey, set[int]] = {}
    for pair_id, part_id, rank, material_id in session.execute(
        sa.select(m.Assignment.pair_id, m.Assignment.part_id, m.Assignment.rank, m.Assignment.material_id)
        .where(m.Assignment.method_key == method_key, m.Assignment.pair_id.in_(list(pair_ids)))
    ):
        key = (pair_id, part_id)
        ranked.setdefault(key, set())
        if material_id is not None:
            ranked[key].add(material_id)
        if rank == 1:
            first[key] = material_id
    return {key: PartFit(first.get(key), frozenset(ids)) for key, ids in ranked.items()}
