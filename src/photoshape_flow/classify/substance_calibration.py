"""Calibrating a part's substance confidence before it weights the material ranking (section 5.2.4).

Why: inference multiplies the classifier's material probabilities by the substance network's
confidence for each material's substance, and (by default) by a colour likelihood: a product of
experts. A product only weighs its experts right when each is calibrated, and the part-level
substance confidence is not: it is the *mean* over the part's pixels of per-pixel probabilities
(`classify.substance_parts`), an average of noisy opinions whose spread says little about how often
the part-level answer is right (on the medium demo it is too flat). Too flat, the network's word is
overruled by the other experts; too sharp, it silences them.

The fix is temperature scaling (Guo et al. 2017) at the part level,

    p_T(s) = p(s)^(1/T) / sum_s' p(s')^(1/T),

with the one parameter T fit by maximum likelihood of the true part substances of *validation*
renders (shapes and envmaps the network never trained on, exact per-pixel part and substance
labels; `pipeline.substances.substance_temperature`): never on exemplars. T < 1 sharpens, T > 1
flattens; T does not change the network's argmax, so the substance the no-classifier baseline and
`part_substance` report is unchanged.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.vocab import SUBSTANCES

log = logging.getLogger(__name__)

MIN_TEMPERATURE = 0.05
MAX_TEMPERATURE = 20.0
MIN_PARTS = 20  # fewer validation parts than this: too few to fit, the confidence is left as it is
_EPS = 1e-6


def temper(probs: Mapping[str, float] | None, temperature: float | None) -> dict[str, float]:
    """Substance probabilities raised to 1/T and renormalised over SUBSTANCES (other keys dropped).

    None or 1.0 returns the substances' probabilities renormalised; empty input gives an empty dict.
    """
    if not probs:
        return {}
    values = np.array([max(float(probs.get(s, 0.0) or 0.0), 0.0) for s in SUBSTANCES], np.float64)
    if values.sum() <= 0:
        return {}
    if temperature is not None and temperature != 1.0:
        impossible = values <= 0.0
        logp = np.log(np.maximum(values, _EPS)) / float(temperature)
        values = np.exp(logp - logp.max())
        values[impossible] = 0.0
    values /= values.sum()
    return {s: float(v) for s, v in zip(SUBSTANCES, values, strict=True)}


def nll(probs: np.ndarray, truth: Sequence[int] | np.ndarray, temperature: float = 1.0) -> float:
    """Mean negative log-likelihood of the true substances under probabilities (N, |S|) tempered by T."""
    return _nll(np.log(np.maximum(np.asarray(probs, np.float64), _EPS)), np.asarray(truth, np.int64), temperature)


def _nll(logp: np.ndarray, truth: np.ndarray, temperature: float) -> float:
    z = logp / temperature
    z = z - z.max(axis=1, keepdims=True)
    log_norm = np.log(np.exp(z).sum(axis=1))
    return float(-(z[np.arange(len(truth)), truth] - log_norm).mean())


def fit_temperature(probs: np.ndarray, truth: Sequence[int] | np.ndarray) -> float | None:
    """Maximum-likelihood temperature for part substance probabilities (N, |S|) and true indices (N,).

    Golden-section search on log T in [MIN_TEMPERATURE, MAX_TEMPERATURE] (the NLL of temperature
    scaling is unimodal in T); None when there are fewer than MIN_PARTS parts.
    """
    p = np.asarray(probs, np.float64)
    t = np.asarray(truth, np.int64)
    if p.ndim != 2 or len(p) != len(t):
        raise ValueError(f"probs must be (N, S) and truth (N,), got {p.shape} and {t.shape}")
    if len(t) < MIN_PARTS:
        return None
    logp = np.log(np.maximum(p, _EPS))
    lo, hi = np.log(MIN_TEMPERATURE), np.log(MAX_TEMPERATURE)
    ratio = (np.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fa, fb = _nll(logp, t, np.exp(a)), _nll(logp, t, np.exp(b))
    for _ in range(60):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - ratio * (hi - lo)
            fa = _nll(logp, t, np.exp(a))
        else:
            lo, a, fa = a, b, fb
            b = lo + ratio * (hi - lo)
            fb = _nll(logp, t, np.exp(b))
    return float(np.exp((lo + hi) / 2.0))


@dataclass
class CalibrationSet:
    """Part-level substance probabilities (N, |S|) and the true substance index of each part."""

    probs: np.ndarray
    truth: np.ndarray

    def __len__(self) -> int:
        return len(self.truth)


def part_calibration_set(
    predictions: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], *, min_fraction: float = 0.005
) -> CalibrationSet:
    """Parts of rendered images as (substance probs (6, H, W), part-ID map, substance-ID map) triples.

    Each part (non-zero part ID covering at least `min_fraction` of the image) contributes its
    `part_substances` probabilities and its true substance, the majority substance label under it
    (labels are SUBSTANCE_LABELS indices: 0 background, 1.. substances).
    """
    rows: list[list[float]] = []
    truth: list[int] = []
    for probs, part_ids, substance_ids in predictions:
        if part_ids.shape != probs.shape[1:] or substance_ids.shape != part_ids.shape:
            raise ValueError(f"maps differ in size: probs {probs.shape[1:]}, parts {part_ids.shape}, "
                             f"substances {substance_ids.shape}")
        minimum = max(1, int(np.ceil(min_fraction * part_ids.size)))
        indices = [int(v) for v, c in zip(*np.unique(part_ids, return_counts=True), strict=True) if v and c >= minimum]
        for result in part_substances(part_ids, probs, indices):
            labels = substance_ids[part_ids == result.part_index]
            labels = labels[(labels > 0) & (labels <= len(SUBSTANCES))]
            if not result.observed or labels.size == 0:
                continue
            rows.append([result.probs[s] for s in SUBSTANCES])
            truth.append(int(np.bincount(labels).argmax()) - 1)
    return CalibrationSet(np.asarray(rows, np.float64).reshape(-1, len(SUBSTANCES)), np.asarray(truth, np.int64))
