"""The ranking policy: how the evidence about one region becomes an ordered list of materials.

Inference (every pair's parts), `photoshape retrieve` (any photo's regions) and the experiments all
rank through `rank_part`, so a change to the policy is made once and measured everywhere. The
evidence of a region (`PartEvidence`) is multiplied as a product of experts:

- the material head's softmax probability of each material (paper, section 5.2);
- the substance confidence of the material's substance (section 5.2.4), calibrated per network on
  validation renders (`classify.substance_calibration`; the caller passes the tempered vector);
- the colour likelihood of the region's median colour under each material (`classify.color_prior`).

The product is an unnormalised posterior: its values are tiny (three factors below 1) and mean
nothing on their own, so each ranked material also carries its `posterior`, the score divided by
the sum over every enabled material (`posterior`), which a user can threshold ("every part at
least 0.5") and whose reliability the training stage measures on validation renders
(`pipeline.calibration.posterior_reliability`).

The first material is then taken from the substance with the most ranking mass, the rest follow by
score (`substance_first_order`). A region smaller than the classifier's smallest training region is
ranked without the head (it never saw such masks: its output there is noise) and takes the
substance decided by other evidence (the substance network's vote) when that is known. Disabled
materials can neither be ranked nor lend their substance mass. The reasons and measurements behind
each rule are records in docs/decisions.md.

Pure: arrays in, `Ranked` lists out; no torch, database or files.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np

from photoshape_flow.vocab import SUBSTANCE_LABELS


@dataclass(frozen=True)
class Ranked:
    """One ranked material for a region."""

    material_id: int
    substance: str
    score: float  # the product of the evidence used (the order's key, except for the substance-first pick)
    probability: float  # the material head's softmax probability (its evidence alone)
    posterior: float  # the score normalised over every enabled material of the policy (they sum to 1)


@dataclass(frozen=True)
class RankingPolicy:
    """The materials a classifier ranks and the rules applied to every region."""

    materials: tuple[int, ...]  # the material head's outputs after background, in order
    material_substances: tuple[str, ...]
    substance_first: bool = True
    min_region_fraction: float = 0.0  # below it (share of the image) the head is not evidence
    enabled: Collection[int] | None = None  # None: every material may be ranked

    def substance_columns(self) -> np.ndarray:
        """Column of SUBSTANCE_LABELS for each material."""
        return np.array([SUBSTANCE_LABELS.index(s) for s in self.material_substances], dtype=np.int64)


@dataclass(frozen=True)
class PartEvidence:
    """What is known about one region. Every term is optional; a missing term weighs nothing.

    material_probs: the head's softmax over [background, *policy.materials].
    substance_weights: a weight per SUBSTANCE_LABELS entry (calibrated confidence, or one-hot for a
        substance known from elsewhere).
    color_weights: the colour likelihood per material of the policy.
    region_fraction: the region's share of the image (None: not a measured region, e.g. unobserved).
    substance: the substance decided by other evidence (the substance network's per-pixel vote).
    """

    material_probs: np.ndarray | None = None
    substance_weights: np.ndarray | None = None
    color_weights: np.ndarray | None = None
    region_fraction: float | None = None
    substance: str | None = None


@dataclass(frozen=True)
class RankedPart:
    materials: list[Ranked]
    head_used: bool  # False when the region was too small for the material head


def substance_first_order(scores: np.ndarray, substances: Sequence[str], substance: str | None = None) -> np.ndarray:
    """Material indices for one region, best first, deciding the substance before the material.

    The first material is the best-scoring one of the substance with the most ranking mass (the sum
    of its materials' scores); the others follow by score. The scores are an (unnormalised)
    posterior over materials, and the substance that posterior believes most is the sum over the
    substance's materials, not the substance of the single best material, which a cluster of
    similar materials of another substance can outvote by splitting the mass. A given `substance`
    (decided by other evidence) is taken instead, when any of its materials has a positive score.
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(substances)
    order = np.argsort(-scores, kind="stable")
    if order.size == 0:
        return order
    mass = {name: float(scores[labels == name].sum()) for name in dict.fromkeys(labels.tolist())}
    best = max(mass, key=lambda name: mass[name])  # ties: the first substance in material order
    if substance is not None and mass.get(substance, 0.0) > 0.0:
        best = substance
    first = next(int(i) for i in order if labels[i] == best)
    return np.concatenate([[first], order[order != first]]).astype(np.int64)


def scores(policy: RankingPolicy, evidence: PartEvidence) -> np.ndarray:
    """The product of the evidence terms per material of the policy (background dropped)."""
    if evidence.material_probs is None:
        out = np.ones(len(policy.materials), np.float32)
    else:
        out = np.asarray(evidence.material_probs)[1:]
    if evidence.substance_weights is not None:
        out = out * np.asarray(evidence.substance_weights)[policy.substance_columns()]
    if evidence.color_weights is not None:
        out = out * np.asarray(evidence.color_weights)
    return out


def enabled_mask(policy: RankingPolicy) -> np.ndarray:
    """True for each material of the policy that may be ranked."""
    if policy.enabled is None:
        return np.ones(len(policy.materials), bool)
    return np.array([mid in policy.enabled for mid in policy.materials], bool)


def posterior(policy: RankingPolicy, values: np.ndarray) -> np.ndarray:
    """`values` (the scores) normalised to a distribution over the enabled materials, summing to 1.

    Disabled materials get 0. When no enabled material has a positive finite score (every expert
    vetoed them all) the posterior is uniform over the enabled ones: it says "no idea", not "certain".
    """
    allowed = enabled_mask(policy)
    raw = np.asarray(values, np.float64)
    masked = np.where(allowed & np.isfinite(raw), np.clip(raw, 0.0, None), 0.0)
    total = float(masked.sum())
    if total > 0.0:
        return masked / total
    return allowed / max(int(allowed.sum()), 1)


def rank_part(evidence: PartEvidence, policy: RankingPolicy, k: int) -> RankedPart:
    """The k best materials for one region under the policy, best first."""
    small = (evidence.region_fraction is not None and evidence.material_probs is not None
             and evidence.region_fraction < policy.min_region_fraction)
    decided = evidence.substance if small else None
    used = PartEvidence(
        material_probs=None if small else evidence.material_probs,
        substance_weights=evidence.substance_weights,
        color_weights=_allowed(policy, evidence.color_weights),
    )
    values = scores(policy, used)
    if policy.substance_first:
        order = substance_first_order(values, policy.material_substances, decided)
    else:
        order = np.argsort(-values, kind="stable")
    head = np.asarray(evidence.material_probs)[1:] if evidence.material_probs is not None else None
    normalised = posterior(policy, values)
    ranked = [
        Ranked(policy.materials[i], policy.material_substances[i], float(values[i]),
               float(head[i]) if head is not None else 1.0, float(normalised[i]))
        for i in order if policy.enabled is None or policy.materials[i] in policy.enabled
    ]
    return RankedPart(ranked[: max(0, k)], head_used=not small)


def _allowed(policy: RankingPolicy, color_weights: np.ndarray | None) -> np.ndarray | None:
    """Colour weights with disabled materials zeroed (they lend no substance mass either)."""
    if policy.enabled is None:
        return color_weights
    allowed = enabled_mask(policy).astype(np.float64)
    return allowed if color_weights is None else np.asarray(color_weights) * allowed
