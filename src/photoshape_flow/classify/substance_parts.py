"""A substance per aligned part from per-pixel substance probabilities (section 4.3).

Rule (the paper's "most overlap", the original's "most common non-background substance"):

- votes: each pixel of the part votes for its argmax label over all six labels; background votes are
  ignored (the aligned part map says the pixel is foreground, so a background argmax is a network
  error). If every pixel of the part votes background, the argmax over the five substances alone is
  used instead, so an observed part always gets a substance;
- winner: the substance with most votes; ties go to the higher mean probability, then SUBSTANCES order;
- confidence: the mean over the part's pixels of the winner's probability *given foreground*,
  p_s / (1 - p_background), i.e. the probabilities renormalised over the five substances (as the
  paper renormalises MINC over its kept categories). `probs` holds that mean for every substance
  (it sums to 1) and `background_prob` the mean raw background probability;
- parts with fewer than `min_pixels` pixels are unobserved: observed=False, substance None,
  confidence None. They are never guessed here; the training-render prior handles them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from photoshape_flow.vocab import SUBSTANCE_LABELS, SUBSTANCES

_EPS = 1e-8


@dataclass
class PartSubstanceResult:
    part_index: int
    observed: bool
    substance: str | None
    confidence: float | None
    pixel_count: int
    probs: dict[str, float] = field(default_factory=dict)
    background_prob: float | None = None
    votes: dict[str, int] = field(default_factory=dict)


def part_substances(
    part_map: np.ndarray,
    substance_probs: np.ndarray,
    part_indices: Iterable[int],
    *,
    min_pixels: int = 1,
) -> list[PartSubstanceResult]:
    """One result per index in `part_indices` (order kept), from a part map (H, W) and probs (6, H, W)."""
    part_map = np.asarray(part_map)
    probs = np.asarray(substance_probs, np.float64)
    if probs.ndim != 3 or probs.shape[0] != len(SUBSTANCE_LABELS):
        raise ValueError(f"substance_probs must be ({len(SUBSTANCE_LABELS)}, H, W), got {probs.shape}")
    if part_map.shape != probs.shape[1:]:
        raise ValueError(f"part map {part_map.shape} and probabilities {probs.shape[1:]} differ in size")

    argmax = probs.argmax(axis=0)
    results: list[PartSubstanceResult] = []
    for index in part_indices:
        mask = part_map == int(index)
        count = int(mask.sum())
        if count < max(1, min_pixels):
            results.append(PartSubstanceResult(int(index), False, None, None, count))
            continue
        p = probs[:, mask]  # (6, n)
        background = p[0]
        conditional = p[1:] / np.maximum(p[1:].sum(axis=0, keepdims=True), _EPS)  # (5, n)
        mean_cond = conditional.mean(axis=1)
        labels = argmax[mask]
        votes = np.bincount(labels, minlength=len(SUBSTANCE_LABELS))[1:]
        if votes.sum() == 0:
            votes = np.bincount(conditional.argmax(axis=0), minlength=len(SUBSTANCES))
        order = sorted(range(len(SUBSTANCES)), key=lambda k: (-votes[k], -mean_cond[k], k))
        winner = order[0]
        results.append(
            PartSubstanceResult(
                part_index=int(index),
                observed=True,
                substance=SUBSTANCES[winner],
                confidence=float(mean_cond[winner]),
                pixel_count=count,
                probs={s: float(mean_cond[k]) for k, s in enumerate(SUBSTANCES)},
                background_prob=float(background.mean()),
                votes={s: int(votes[k]) for k, s in enumerate(SUBSTANCES)},
            )
        )
    return results
