"""The fit cost's weights and its softmax temperature, fitted by conditional-logit maximum likelihood.

The fit stage ranks a part's candidates by ``cost = w . x`` where x holds the candidate's distance
terms (colour, contrast, gradient, highlight, deep; `fit.appearance.terms`) and its ranking prior cost (-log prior),
and turns costs into scores with ``softmax(-cost / T)`` (`fit.select.scores_of`). Given cases where
the true candidate is known (validation renders made to look like photos, `fitting.calibration`),
the weights and the temperature that make the true candidate most probable are the maximum of the
conditional-logit likelihood ``prod_i softmax(-X_i theta)[true_i]`` with ``theta = w / T >= 0``.

Only theta is identifiable (scaling w and T together changes nothing), so the fit returns w
normalised to sum to 1 and T = 1 / sum(theta): the weights say how the evidence is shared, the
temperature how sharp the posterior is. A small L2 penalty, ``l2 |theta - centre|^2`` added to the
summed log-likelihood (a Gaussian prior on theta), keeps the fit finite when the training cases are
separable (then the likelihood grows without bound with |theta|) and, centred on the hand-set
weights, keeps a fit on a handful of cases near them; with many cases the data dominate.
Deterministic: L-BFGS-B from a fixed start, no randomness.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, minimize_scalar
from scipy.special import logsumexp

TERMS = ("color", "contrast", "gradient", "highlight", "deep", "prior")  # the columns of a case's features
L2 = 1.0  # penalty on |theta - centre|^2 against the summed log-likelihood (a prior worth ~1 case)


@dataclass(frozen=True)
class Case:
    """One observed part: each candidate's feature row (`TERMS`) and the row of the true candidate."""

    features: np.ndarray  # (candidates, len(TERMS)), finite
    truth: int
    group: str = ""  # what the case came from (a render key): cases of one group stay in one fold


@dataclass(frozen=True)
class Fit:
    """Fitted weights (in `TERMS` order, summing to 1) and the temperature dividing the cost."""

    weights: tuple[float, ...]
    temperature: float

    @property
    def theta(self) -> np.ndarray:
        return np.asarray(self.weights, np.float64) / self.temperature

    @classmethod
    def from_theta(cls, theta: np.ndarray) -> Fit:
        total = float(np.sum(theta))
        if total <= 0:  # nothing informative: every candidate equally likely
            return cls(tuple(1.0 / len(theta) for _ in theta), float("inf"))
        return cls(tuple(float(t) / total for t in theta), 1.0 / total)


@dataclass(frozen=True)
class Score:
    """How well a theta predicts cases: mean negative log-likelihood of the truth, and top-1."""

    log_loss: float
    top1: float
    cases: int


def usable(cases: Sequence[Case]) -> list[Case]:
    """Cases that can inform a fit: at least two candidates, finite features, a valid truth row."""
    return [c for c in cases if c.features.ndim == 2 and c.features.shape[0] >= 2 and c.features.shape[1] == len(TERMS)
            and 0 <= c.truth < c.features.shape[0] and bool(np.isfinite(c.features).all())]


def _stack(cases: Sequence[Case]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (n, C, terms) zero-padded, padding mask (n, C), truth (n,)): one array for all cases."""
    width = max(c.features.shape[0] for c in cases)
    x = np.zeros((len(cases), width, len(TERMS)))
    pad = np.ones((len(cases), width), bool)
    for i, c in enumerate(cases):
        x[i, : c.features.shape[0]] = c.features
        pad[i, : c.features.shape[0]] = False
    return x, pad, np.array([c.truth for c in cases])


def _logits(theta: np.ndarray, x: np.ndarray, pad: np.ndarray) -> np.ndarray:
    return np.where(pad, -np.inf, -(x @ theta))


def _objective(theta: np.ndarray, x: np.ndarray, pad: np.ndarray, truth: np.ndarray,
               l2: float, centre: np.ndarray | float = 0.0) -> tuple[float, np.ndarray]:
    """Mean negative log-likelihood of the true candidates plus l2 |theta - centre|^2 / n, and its gradient."""
    logits = _logits(theta, x, pad)
    norm = logsumexp(logits, axis=1)
    rows = np.arange(len(truth))
    p = np.exp(logits - norm[:, None])
    loss = float(np.mean(norm - logits[rows, truth]))
    grad = np.mean(x[rows, truth] - np.einsum("nc,nct->nt", p, x), axis=0)
    shrink = l2 / len(truth)
    return loss + shrink * float((theta - centre) @ (theta - centre)), grad + 2.0 * shrink * (theta - centre)


def fit(cases: Sequence[Case], start: Sequence[float] | None = None, l2: float = L2,
        centre: Sequence[float] | None = None) -> Fit:
    """Non-negative weights and a temperature maximising the penalised likelihood of the true candidates.

    `centre`: theta the penalty pulls towards (default 0); `start`: where L-BFGS-B starts (default 1s).
    """
    cases = usable(cases)
    if not cases:
        raise ValueError("no usable calibration case (each needs two candidates and its true one)")
    x0 = np.asarray(start if start is not None else np.ones(len(TERMS)), np.float64)
    c = np.zeros(len(TERMS)) if centre is None else np.asarray(centre, np.float64)
    result = minimize(_objective, x0, args=(*_stack(cases), l2, c), jac=True, method="L-BFGS-B",
                      bounds=[(0.0, None)] * len(TERMS), options={"maxiter": 500, "gtol": 1e-8})
    return Fit.from_theta(np.maximum(result.x, 0.0))


def fit_temperature(cases: Sequence[Case], weights: Sequence[float]) -> float:
    """The temperature alone for fixed weights (what calibrating the hand-set cost would give)."""
    cases = usable(cases)
    w = np.asarray(weights, np.float64)
    if not cases:
        raise ValueError("no usable calibration case")
    stacked = _stack(cases)
    result = minimize_scalar(lambda log_t: _objective(w / np.exp(log_t), *stacked, 0.0)[0], bounds=(-6.0, 6.0),
                             method="bounded", options={"xatol": 1e-6})
    return float(np.exp(result.x))


def score(theta: np.ndarray, cases: Sequence[Case]) -> Score:
    """Mean log-loss and top-1 (ties count against) of `theta` on `cases`."""
    cases = usable(cases)
    if not cases:
        return Score(float("nan"), float("nan"), 0)
    x, pad, truth = _stack(cases)
    logits = _logits(np.asarray(theta, np.float64), x, pad)
    rows = np.arange(len(truth))
    true = logits[rows, truth]
    logits[rows, truth] = -np.inf
    hits = true > logits.max(axis=1)  # ties count against
    losses = np.logaddexp(logsumexp(logits, axis=1), true) - true
    return Score(float(np.mean(losses)), float(np.mean(hits)), len(cases))


def folds(cases: Sequence[Case]) -> tuple[list[Case], list[Case]]:
    """Two halves by group (alternating over the sorted group names): a render's parts stay together."""
    groups = sorted({c.group for c in cases})
    first = set(groups[::2])
    return [c for c in cases if c.group in first], [c for c in cases if c.group not in first]
