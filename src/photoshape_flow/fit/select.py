"""The batched render plan and the ranking of each part's candidates by cost.

Parts occupy separate pixels, so one render can test a candidate on every part at once: render j
gives each part its j-th candidate (a part with fewer candidates keeps its first), and the number of
renders is the longest candidate list, not the sum. Inter-reflection between parts is the price
(small for isolated furniture). Cost = appearance distance + prior_weight * (-log prior).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from photoshape_flow.fit.candidates import Candidate


@dataclass(frozen=True)
class Scored:
    candidate: Candidate
    distance: float | None  # None: the part was not visible in the render (only the prior decides)
    cost: float


def render_slots(candidates: Mapping[int, Sequence[Candidate]]) -> list[dict[int, int]]:
    """Render j -> {part: material id}: every part's j-th candidate, or its first past the end of its list."""
    longest = max((len(c) for c in candidates.values()), default=0)
    return [{part: (c[j] if j < len(c) else c[0]).material_id for part, c in candidates.items() if c}
            for j in range(longest)]


def rank_candidates(candidates: Sequence[Candidate], distances: Mapping[int, float | None],
                    prior_weight: float) -> list[Scored]:
    """Candidates best first by cost; a missing distance counts as the mean of the measured ones."""
    measured = [d for d in distances.values() if d is not None and math.isfinite(d)]
    fill = sum(measured) / len(measured) if measured else 0.0
    scored = []
    for c in candidates:
        d = distances.get(c.material_id)
        d = d if d is not None and math.isfinite(d) else None
        scored.append(Scored(c, d, (fill if d is None else d) + prior_weight * c.prior_cost))
    return sorted(scored, key=lambda s: s.cost)


def scores_of(ranked: Sequence[Scored], temperature: float = 1.0) -> list[float]:
    """exp(-cost / temperature) normalised over the part's candidates: a score where higher is better.

    With the temperature fitted on validation renders (`fit.calibrate`) the score is a calibrated
    posterior over the candidates; an infinite temperature (no evidence) makes them uniform.
    """
    if not ranked:
        return []
    low = min(s.cost for s in ranked)
    t = max(float(temperature), 1e-9)
    weights = [math.exp(-(s.cost - low) / t) for s in ranked]
    total = sum(weights)
    return [w / total for w in weights]
