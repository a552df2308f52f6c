"""A material classifier's evidence about a region, built one way for every caller of `rank_part`.

The inference stage (each part of a pair), the training stage's posterior check and the fit
calibration (regions of validation renders), `photoshape retrieve` (any photo's regions) and the
experiments all rank a classifier's regions through `classify.ranking.rank_part`. `ClassifierEvidence`
is what they share: the classifier's ranking policy (its materials, its smallest training region,
the materials that may be ranked) and its stored colour prior; `region` turns the networks'
outputs for one region into its `PartEvidence` (material head, substance weights, colour
likelihood of the region's median colour, the region's share of the image) and `unobserved` does
so for a part too small to see. What each caller passes as substance weights is its own: inference
the calibrated substance network's part confidence, the calibrations and `retrieve` the
classifier's own substance head.

The smallest training region comes from the classifier row's `config`; a row whose config lacks it
(trained before the key was stored) takes the training default, `ClassifierConfig.min_region_fraction`,
as the inference stage always has (`min_region_fraction`).

Pure: arrays in, `PartEvidence` / `RankedPart` out; no torch, database or files.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from photoshape_flow.classify.assignment import median_lab, one_substance, substance_vector
from photoshape_flow.classify.color_prior import color_likelihood
from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.classify.ranking import PartEvidence, RankedPart, RankingPolicy, rank_part

ColorPrior = tuple[np.ndarray, float]  # (CIELAB of the classifier's materials in its order, sigma)


class PolicySource(Protocol):
    """What the builder needs of a classifier (`classify.infer.MaterialClassifier` is one)."""

    def policy(self, min_region_fraction: float = ..., substance_first: bool = ...,
               enabled: Collection[int] | None = ...) -> RankingPolicy: ...


def min_region_fraction(config: Mapping[str, Any] | None) -> float:
    """The smallest region (share of the image) a classifier trained on, from its row's `config`.

    Below it the head's output is not evidence (validation renders: top-1 0.08, substance of top-1
    at chance). A config without the key gets the training default.
    """
    return float((config or {}).get("min_region_fraction", ClassifierConfig.min_region_fraction))


def region_fraction(mask: np.ndarray) -> float:
    """A region's share of its image."""
    return float(mask.sum()) / mask.size


@dataclass(frozen=True)
class ClassifierEvidence:
    """The ranking policy and colour prior of one classifier; builds and ranks its regions' evidence."""

    policy: RankingPolicy
    color_prior: ColorPrior | None = None  # None: no colour likelihood (not calibrated, or not wanted)

    @classmethod
    def for_classifier(cls, classifier: PolicySource, config: Mapping[str, Any] | None, *,
                       enabled: Collection[int] | None = None,
                       color_prior: ColorPrior | None = None) -> ClassifierEvidence:
        """The builder of a classifier whose row's config is `config`; `enabled`: the materials that may be
        ranked (None: every one of the classifier's)."""
        return cls(classifier.policy(min_region_fraction(config), enabled=enabled), color_prior)

    def colors(self, lab: np.ndarray | None) -> np.ndarray | None:
        """The colour likelihood of a median CIELAB colour per material (None without a colour prior)."""
        return None if self.color_prior is None else color_likelihood(lab, *self.color_prior)

    def of_lab(self, material_probs: np.ndarray | None, substance_weights: np.ndarray | None,
               lab: np.ndarray | None, *, fraction: float | None = None, substance: str | None = None) -> PartEvidence:
        """The evidence of a region whose median CIELAB colour is `lab` and share of the image `fraction`."""
        return PartEvidence(material_probs=material_probs, substance_weights=substance_weights,
                            color_weights=self.colors(lab), region_fraction=fraction, substance=substance)

    def region(self, material_probs: np.ndarray | None, substance_weights: np.ndarray | None,
               image: np.ndarray, mask: np.ndarray, *, measured: bool = True,
               substance: str | None = None) -> PartEvidence:
        """The evidence of a region of `image` seen by the classifier.

        `measured=False`: the head saw the region enlarged (`retrieve --crop mask`), so its share of
        the image is no reason to drop the head. `substance`: decided by other evidence (taken for a
        region too small for the head).
        """
        return self.of_lab(material_probs, substance_weights, median_lab(image, mask),
                           fraction=region_fraction(mask) if measured else None, substance=substance)

    @staticmethod
    def unobserved(material_probs: np.ndarray | None, substance: str | None) -> PartEvidence:
        """A part too small to see: only its (prior) substance's materials, ranked by the head over the object."""
        weights = one_substance(substance) if substance else substance_vector(None)
        return PartEvidence(material_probs=material_probs, substance_weights=weights, substance=substance)

    def rank(self, evidence: PartEvidence, k: int) -> RankedPart:
        return rank_part(evidence, self.policy, k)

    def rank_regions(self, image: np.ndarray, masks: Sequence[np.ndarray], material_probs: np.ndarray,
                     substance_probs: np.ndarray | None, k: int, *, measured: bool = True) -> list[RankedPart]:
        """Each of `masks` ranked on the classifier's outputs for it (row i of both heads' probabilities;
        `substance_probs` None: no substance term)."""
        return [self.rank(self.region(material_probs[i], None if substance_probs is None else substance_probs[i],
                                      image, mask, measured=measured), k)
                for i, mask in enumerate(masks)]
