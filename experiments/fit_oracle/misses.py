"""Where the fit cost's wrong choices come from, read from `run.py --dump` cases (no rendering).

For each dumped condition: how many cases the hand-set cost gets wrong, how many of those pick a
material of another substance than the truth, how often the ranking prior favours the winner, and
how many true materials are candidates only with the prior floor (colour-nearest or new). Then the
2-fold held-out figures (folds by render, as the calibration's) of three models: the hand-set cost,
the fitted cost (the terms of `fit.calibrate.TERMS`), and the fitted cost with the prior split
in two, the classifier's share among its proposals and an indicator "not proposed" (the floor). A
floor candidate is recognised by its prior cost, so a proposed one whose share fell to the floor
counts as not proposed.

    python -m experiments.fit_oracle.misses RESULTS.json [--floor 0.02]

RESULTS.json: `<data root>/experiments/fit_oracle/results.json` of a run with `--dump`.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.fit import calibrate as cal
from photoshape_flow.profiles import FitConfig

SPLIT_TERMS = (*cal.TERMS, "unproposed")
PRIOR = cal.TERMS.index("prior")  # the prior's column in a case's features


def hand_set() -> np.ndarray:
    """The profile's default weights in `fit.calibrate.TERMS` order."""
    c = FitConfig()
    return np.array([c.color_weight, c.contrast_weight, c.gradient_weight, c.highlight_weight, c.deep_weight,
                     c.prior_weight])


def breakdown(records: Sequence[dict[str, Any]], floor_cost: float) -> Counter[str]:
    """Counts of the hand-set cost's misses by kind (see the module docstring)."""
    weights = hand_set()
    out: Counter[str] = Counter()
    for r in records:
        features, truth, substances = np.asarray(r["features"], float), int(r["truth"]), r["substances"]
        winner = int(np.argmin(features @ weights))
        out["cases"] += 1
        out["truth_at_floor"] += int(np.isclose(features[truth, PRIOR], floor_cost, atol=1e-3))
        if winner == truth:
            continue
        out["wrong"] += 1
        out["wrong_other_substance"] += int(substances[winner] != substances[truth])
        out["wrong_prior_favours_winner"] += int(features[truth, PRIOR] > features[winner, PRIOR])
        out["wrong_truth_closer_in_colour"] += int(features[truth, 0] < features[winner, 0])
    return out


def cases_of(records: Sequence[dict[str, Any]], floor_cost: float | None = None) -> list[cal.Case]:
    """The dumped cases; with `floor_cost`, the prior column split into (share, not-proposed indicator)."""
    out = []
    for r in records:
        features = np.asarray(r["features"], float)
        if floor_cost is not None:
            unproposed = np.isclose(features[:, PRIOR], floor_cost, atol=1e-3).astype(float)
            features = np.column_stack([features[:, :PRIOR], np.where(unproposed > 0, 0.0, features[:, PRIOR]),
                                        unproposed])
        out.append(cal.Case(features, int(r["truth"]), r["group"]))
    return out


def held_out(cases: Sequence[cal.Case], theta_of: Callable[[Sequence[cal.Case]], np.ndarray]) -> dict[str, float]:
    """Pooled 2-fold held-out log-loss and top-1 of the theta `theta_of` fits on the other fold."""
    first, second = cal.folds(cases)
    scores = [cal.score(theta_of(train), test) for train, test in ((first, second), (second, first))]
    n = sum(s.cases for s in scores)
    return {"log_loss": round(sum(s.log_loss * s.cases for s in scores) / n, 4),
            "top1": round(sum(s.top1 * s.cases for s in scores) / n, 4), "cases": n}


def models(records: Sequence[dict[str, Any]], floor_cost: float) -> dict[str, Any]:
    """Held-out figures of the hand-set, fitted and split-prior costs, and the split cost's weights."""
    base = hand_set()
    five = cases_of(records)
    out: dict[str, Any] = {"hand_set": held_out(five, lambda _: base),
                           "fitted": held_out(five, lambda train: cal.fit(train, start=base, centre=base).theta)}
    terms = cal.TERMS
    cal.TERMS = SPLIT_TERMS  # `fit.calibrate` checks the column count against it
    try:
        split_base = np.append(base, base[PRIOR] * floor_cost)  # the same costs as the hand-set floor
        split = cases_of(records, floor_cost)
        out["fitted_split"] = held_out(split, lambda train: cal.fit(train, start=split_base, centre=split_base).theta)
        whole = cal.fit(split, start=split_base, centre=split_base)
        out["split_weights"] = dict(zip(SPLIT_TERMS, (round(w, 3) for w in whole.weights), strict=True))
    finally:
        cal.TERMS = terms
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="fit_oracle results.json written with --dump")
    parser.add_argument("--floor", type=float, default=FitConfig().prior_floor, help="the run's fit.prior_floor")
    args = parser.parse_args()
    dumped = json.loads(args.results.read_text()).get("cases")
    if not dumped:
        raise SystemExit(f"{args.results}: no dumped cases (run experiments.fit_oracle.run with --dump)")
    floor_cost = float(-np.log(args.floor))
    for condition, records in dumped.items():
        print(condition, json.dumps({"misses": breakdown(records, floor_cost), **models(records, floor_cost)}))


if __name__ == "__main__":
    main()
