"""Which materials each observed part tries, with the ranking prior each carries.

Three sources, in this order (a material in several keeps its first): the top-K of the part's current
ranking (the classifier's rows), the colour-nearest material of every substance (so a substance the
classifier ruled out still competes with its best-looking material), and every enabled material the
classifier was not trained on (a newly added material competes at once, without retraining).

The prior of a ranked candidate is its ranking score normalised over the part's ranked candidates;
the others get `floor` (they carry no classifier evidence, only the render decides for them).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Candidate:
    material_id: int
    substance: str
    prior: float  # in (0, 1]
    source: str  # "ranking" | "colour" | "new"

    @property
    def prior_cost(self) -> float:
        """-log prior: what the ranking says against this candidate."""
        return -math.log(max(self.prior, 1e-9))


@dataclass(frozen=True)
class RankedRow:
    """One row of the current ranking of a part."""

    material_id: int
    substance: str
    score: float | None


def part_candidates(
    ranked: Sequence[RankedRow],
    top_k: int,
    material_substance: Mapping[int, str],
    material_labs: Mapping[int, np.ndarray],
    part_lab: np.ndarray | None,
    untrained: Collection[int],
    floor: float = 0.02,
) -> list[Candidate]:
    """The candidates of one part (see the module docstring); only enabled materials (`material_substance`)."""
    out: dict[int, Candidate] = {}
    top = [r for r in ranked if r.material_id in material_substance][: max(0, top_k)]
    total = sum(max(r.score or 0.0, 0.0) for r in top)
    for r in top:
        share = (max(r.score or 0.0, 0.0) / total) if total > 0 else 1.0 / len(top)
        out[r.material_id] = Candidate(r.material_id, r.substance, max(share, floor), "ranking")
    if part_lab is not None:
        nearest: dict[str, tuple[float, int]] = {}
        for mid, lab in sorted(material_labs.items()):
            substance = material_substance.get(mid)
            if substance is None:
                continue
            d = float(np.linalg.norm(np.asarray(lab) - part_lab))
            if substance not in nearest or d < nearest[substance][0]:
                nearest[substance] = (d, mid)
        for substance, (_, mid) in sorted(nearest.items()):
            out.setdefault(mid, Candidate(mid, substance, floor, "colour"))
    for mid in sorted(untrained):
        if mid in material_substance:
            out.setdefault(mid, Candidate(mid, material_substance[mid], floor, "new"))
    return list(out.values())
