"""Substance priors for parts whose substance the exemplar does not tell (section 5.1, "Substance Prior").

Two situations need a prior instead of an observed substance:

- the *bootstrap* round, which renders before any substance network exists: the substance of every
  part is drawn from a weak name prior (a keyword in the part name, e.g. "leg" -> wood/metal,
  "cushion" -> fabric/leather), mixed half and half with the uniform distribution so that every
  substance still appears on every kind of part and the substance network learns appearance rather
  than part names; parts without a known keyword get the uniform distribution;
- the *training* round, for parts that are unobserved in the pair's exemplar (no pixels after
  alignment) or have no PartSubstance row: the substances the same part received in the shape's other
  pairs, else the name prior.

Only substances that have at least one enabled material can be drawn; priors are renormalised over
them (a prior with no mass left falls back to uniform over the available substances).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence

from photoshape_flow.vocab import SUBSTANCES

# keyword -> relative weights over SUBSTANCES; the first keyword found in the part name wins.
NAME_PRIOR_KEYWORDS: tuple[tuple[str, Mapping[str, float]], ...] = (
    ("cushion", {"fabric": 0.6, "leather": 0.4}),
    ("pillow", {"fabric": 0.7, "leather": 0.3}),
    ("upholster", {"fabric": 0.6, "leather": 0.4}),
    ("pad", {"fabric": 0.6, "leather": 0.4}),
    ("seat", {"fabric": 0.35, "leather": 0.25, "wood": 0.25, "plastic": 0.15}),
    ("assise", {"fabric": 0.35, "leather": 0.25, "wood": 0.25, "plastic": 0.15}),
    ("back", {"fabric": 0.35, "leather": 0.25, "wood": 0.25, "plastic": 0.15}),
    ("arm", {"wood": 0.35, "fabric": 0.3, "leather": 0.2, "metal": 0.15}),
    ("shoulder", {"fabric": 0.5, "leather": 0.3, "wood": 0.2}),
    ("leg", {"wood": 0.5, "metal": 0.4, "plastic": 0.1}),
    ("feet", {"wood": 0.5, "metal": 0.4, "plastic": 0.1}),
    ("foot", {"wood": 0.5, "metal": 0.4, "plastic": 0.1}),
    ("tube", {"metal": 0.8, "plastic": 0.2}),
    ("frame", {"metal": 0.5, "wood": 0.5}),
    ("base", {"metal": 0.4, "wood": 0.4, "plastic": 0.2}),
    ("wheel", {"plastic": 0.8, "metal": 0.2}),
    ("caster", {"plastic": 0.8, "metal": 0.2}),
)

NAME_PRIOR_WEIGHT = 0.5  # mixture weight of the keyword distribution against uniform


def uniform_prior(available: Iterable[str] = SUBSTANCES) -> dict[str, float]:
    subs = [s for s in SUBSTANCES if s in set(available)]
    if not subs:
        return {}
    return {s: 1.0 / len(subs) for s in subs}


def name_prior(part_name: str | None, weight: float = NAME_PRIOR_WEIGHT) -> dict[str, float]:
    """P(substance | part name): keyword distribution mixed with uniform (uniform without a keyword)."""
    uniform = uniform_prior()
    name = re.sub(r"[^a-z]", " ", (part_name or "").lower())
    for keyword, weights in NAME_PRIOR_KEYWORDS:
        if keyword in name:
            total = sum(weights.values())
            return {s: (1 - weight) * uniform[s] + weight * weights.get(s, 0.0) / total for s in SUBSTANCES}
    return uniform


def empirical_prior(observed: Sequence[str]) -> dict[str, float]:
    """Relative frequencies of substances observed for the same part in other pairs."""
    counts = dict.fromkeys(SUBSTANCES, 0)
    for s in observed:
        if s in counts:
            counts[s] += 1
    total = sum(counts.values())
    if total == 0:
        return {}
    return {s: c / total for s, c in counts.items()}


def observed_prior(observed: str | Mapping[str, float] | None) -> dict[str, float]:
    """What the substance network saw of a part as a distribution: its probabilities, or a label as certain.

    Training renders draw an observed part's substance from this rather than taking the network's
    most likely label: the most likely label of every part turns the network's doubt into its
    favourite substances (small demo: leather in 3% of the parts' labels against 20% of the
    network's own probability mass), and a classifier trained on those renders inherits the bias.
    """
    if observed is None:
        return {}
    if isinstance(observed, str):
        return {observed: 1.0} if observed in SUBSTANCES else {}
    return {s: float(observed[s]) for s in SUBSTANCES if float(observed.get(s, 0.0)) > 0.0}


def restrict(prior: Mapping[str, float], available: Iterable[str]) -> dict[str, float]:
    """Renormalise `prior` over the available substances (uniform over them if no mass is left)."""
    avail = [s for s in SUBSTANCES if s in set(available)]
    if not avail:
        raise ValueError("no substance has an enabled material")
    masses = {s: float(prior.get(s, 0.0)) for s in avail}
    total = sum(masses.values())
    if total <= 0:
        return uniform_prior(avail)
    return {s: m / total for s, m in masses.items()}
