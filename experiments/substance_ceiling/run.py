"""How much substance information does the material classifier add to the substance network on exemplars?

The no-classifier baseline's substance is the substance network's decision; ours can only beat it
on the substance column if the classifier's evidence (material head, its own substance head, the
colour likelihood) says something about a part's substance that the network does not. This experiment
measures that directly from the records of `experiments.substance_ceiling.records`, with no network run:

  - each expert alone: the substance of the network's decision, of the material head's mass per
    substance, of the classifier's substance head, of the colour likelihood's mass; how often the
    network and the head agree, and who is right when they do not;
  - log-linear pools  argmax_s  w . [log N(s), log sum_{m in s} H(m), log (sum_{m in s} H(m) C(m) /
    sum_{m in s} H(m)), log S(s)]  with non-negative weights fit by substance log-likelihood on the
    validation renders' exact regions (a ranking that could be chosen without the exemplars);
  - the same pools with weights fit on half of the exemplars (by exemplar id) and scored on the
    other half, both ways: the test set used on purpose, never a ranking to adopt. If even weights
    fit where they are scored leave the pool at the network's accuracy, no re-weighting of this
    evidence will beat the network there (a maximum-likelihood fit, not a strict accuracy bound).

Also scored: ours with the material head divided by the training renders' substance prior (their
substances follow the network's decisions, so the head's prior echoes the network's; the frequency
is read from the validation regions, which share the training renders' distribution), and each
decision's recall per true substance. With `--aligned` (the JSON of `experiments.aligned_validation.run`,
which records the same evidence) every row is scored on the aligned validation renders too.

Parts below the classifier's smallest training region keep the network's decision (inference-8).
Prints tables and writes <data root>/experiments/substance_ceiling/ceiling.json.

    PHOTOSHAPE_DATA_ROOT=... python -m experiments.substance_ceiling.records
    PHOTOSHAPE_DATA_ROOT=... python -m experiments.substance_ceiling.run [RECORDS] [--aligned ALIGNED_JSON]

RECORDS defaults to the data root's records.json; ALIGNED_JSON is
<data root>/experiments/aligned_validation/aligned_validation.json when that experiment has run.
"""

from __future__ import annotations

import argparse
import json
from functools import partial
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from photoshape_flow.classify.color_prior import color_likelihood
from photoshape_flow.classify.ranking import substance_first_order
from photoshape_flow.config import get_settings
from photoshape_flow.vocab import SUBSTANCES

from ..common import results_dir

POOLS = {"N + H": (0, 1), "N + H + C": (0, 1, 2), "N + S": (0, 3), "N + H + C + S": (0, 1, 2, 3)}


class Region:
    """One record's evidence as arrays (substances in SUBSTANCES order)."""

    def __init__(self, r: dict, labs: np.ndarray, sigma: float | None, member: np.ndarray, min_fraction: float):
        n = np.maximum(np.asarray(r["network_probs"], np.float64), 1e-6)
        self.n = n / n.sum()
        self.h = np.maximum(np.asarray(r["head"][1:], np.float64), 1e-12)
        known = r.get("lab") is not None and sigma is not None
        self.c = np.maximum(color_likelihood(r["lab"], labs, sigma), 1e-300) if known else np.ones(len(self.h))
        s = np.maximum(np.asarray(r["head_substance"][1:], np.float64), 1e-6)
        self.s = s / s.sum()
        self.small = r["fraction"] < min_fraction
        self.truth = SUBSTANCES.index(r["true_substance"])
        self.net = SUBSTANCES.index(r["network"])
        self.group = int(r.get("exemplar", r.get("render", 0)))
        hm = member @ self.h
        self.x = np.stack([np.log(self.n), np.log(hm), np.log(np.maximum(member @ (self.h * self.c), 1e-300) / hm),
                           np.log(self.s)], axis=1)  # (S, 4)


def fit_pool(regions: list[Region], cols: tuple[int, ...]) -> np.ndarray:
    """Non-negative weights maximising the substance log-likelihood of the pool."""
    x = np.stack([r.x[:, cols] for r in regions])
    y = np.array([r.truth for r in regions])

    def nll(w: np.ndarray) -> float:
        z = x @ w
        z = z - z.max(axis=1, keepdims=True)
        return float(-(z[np.arange(len(y)), y] - np.log(np.exp(z).sum(axis=1))).mean())

    return minimize(nll, np.ones(len(cols)), method="L-BFGS-B", bounds=[(0.0, 20.0)] * len(cols)).x


def pool_decision(r: Region, cols: tuple[int, ...], w: np.ndarray) -> int:
    return r.net if r.small else int(np.argmax(r.x[:, cols] @ w))


def accuracy(regions: list[Region], decide) -> float:
    return float(np.mean([decide(r) == r.truth for r in regions])) if regions else float("nan")


def agree(regions: list[Region], member: np.ndarray) -> dict[str, float]:
    """How often the network's decision and the material head's substance agree, and who is right when not."""
    net = np.array([r.net for r in regions])
    head = np.array([int(np.argmax(member @ r.h)) for r in regions])
    truth = np.array([r.truth for r in regions])
    differ = net != head
    return {"parts": len(regions), "agree": float(np.mean(~differ)),
            "accuracy_when_agree": float(np.mean((net == truth)[~differ])),
            "disagree_network_right": float(np.mean((net == truth)[differ])),
            "disagree_head_right": float(np.mean((head == truth)[differ]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("records", type=Path, nargs="?",
                        help="experiments.substance_ceiling.records output (default: the data root's records.json)")
    parser.add_argument("--aligned", type=Path,
                        help="experiments.aligned_validation.run output (with the substance head)")
    parser.add_argument("--out", type=Path, help="default: <data root>/experiments/substance_ceiling/ceiling.json")
    args = parser.parse_args()
    folder = results_dir(get_settings(), "substance_ceiling")
    records_path = args.records or folder / "records.json"
    out = args.out or folder / "ceiling.json"
    data = json.loads(records_path.read_text())
    subs = np.asarray(data["material_substances"])
    member = np.stack([subs == s for s in SUBSTANCES]).astype(np.float64)
    labs = np.asarray(data["labs"], np.float64)
    sigma, temperature, min_fraction = data["color_sigma"], data["temperature"] or 1.0, data["min_region_fraction"]
    val = [Region(r, labs, sigma, member, min_fraction) for r in data["validation"]]
    ex = [Region(r, labs, sigma, member, min_fraction) for r in data["exemplars"]]
    large = [r for r in ex if not r.small]
    aligned = ([Region(r, labs, sigma, member, min_fraction) for r in json.loads(args.aligned.read_text())["records"]]
               if args.aligned else [])
    sets = {"validation": val, "aligned": aligned, "aligned, large parts": [r for r in aligned if not r.small],
            "exemplars": ex, "exemplars, large parts": large}
    sets = {k: v for k, v in sets.items() if v}
    of_material = [SUBSTANCES.index(s) for s in subs]
    train_prior = np.array([np.mean([r.truth == k for r in val]) for k in range(len(SUBSTANCES))])

    def inference_8(r: Region, prior: np.ndarray | None = None) -> int:
        nt = np.exp(np.log(r.n) / temperature)
        head = np.ones_like(r.h) if r.small else r.h
        if prior is not None and not r.small:
            head = head / np.maximum(prior[of_material], 1e-6)
        scores = head * (nt / nt.sum())[of_material] * r.c
        return SUBSTANCES.index(subs[substance_first_order(scores, subs, SUBSTANCES[r.net] if r.small else None)[0]])

    experts = {
        "network decision (no-classifier's substance)": lambda r: r.net,
        "material head: substance with most mass": lambda r: int(np.argmax(member @ r.h)),
        "classifier's substance head": lambda r: int(np.argmax(r.s)),
        "colour likelihood: substance with most mass": lambda r: int(np.argmax(member @ r.c / member.sum(axis=1))),
        "ours, inference-8 (the pipeline)": inference_8,
        "ours, head divided by the training substance prior": lambda r: inference_8(r, train_prior),
    }
    rows: dict[str, dict[str, float]] = {}
    for name, decide in experts.items():
        rows[name] = {k: accuracy(v, decide) for k, v in sets.items()}
    recall = {name: {k: {s: accuracy([r for r in v if r.truth == i], decide) for i, s in enumerate(SUBSTANCES)}
                     for k, v in sets.items() if k.endswith("large parts") or k == "validation"}
              for name, decide in experts.items()}
    shares = {k: {s: float(np.mean([r.truth == i for r in v])) for i, s in enumerate(SUBSTANCES)}
              for k, v in sets.items()}
    weights: dict[str, list[float]] = {}
    for name, cols in POOLS.items():
        w = fit_pool(val, cols)
        weights[f"validation fit {name}"] = w.round(3).tolist()
        decide = partial(pool_decision, cols=cols, w=w)
        rows[f"pool {name}, fit on validation renders"] = {k: accuracy(v, decide) for k, v in sets.items()}
        hits: list[bool] = []
        hits_large: list[bool] = []
        for half in (0, 1):
            w_half = fit_pool([r for r in large if r.group % 2 == half], cols)
            weights[f"exemplar fit {name}, exemplars % 2 == {half}"] = w_half.round(3).tolist()
            test = [r for r in ex if r.group % 2 != half]
            hits += [pool_decision(r, cols, w_half) == r.truth for r in test]
            hits_large += [pool_decision(r, cols, w_half) == r.truth for r in test if not r.small]
        rows[f"pool {name}, fit on the other half of the exemplars"] = {
            "exemplars": float(np.mean(hits)), "exemplars, large parts": float(np.mean(hits_large))}
    agreement = {k: agree(v, member) for k, v in sets.items() if k.endswith("large parts") or k == "validation"}
    print(f"{len(val)} validation regions, {len(ex)} exemplar parts ({len(large)} of training size); "
          f"network T {temperature:.3f}, colour sigma {sigma}")
    print(f"\n| substance decided by | {' | '.join(sets)} |\n|---|{'---:|' * len(sets)}")
    for name, r in rows.items():
        cells = " | ".join(f"{r[k]:.4f}" if k in r else "—" for k in sets)
        print(f"| {name} | {cells} |")
    print("\nshare of each true substance: " + "; ".join(
        f"{k} " + ", ".join(f"{s} {v:.2f}" for s, v in share.items()) for k, share in shares.items()))
    print("recall per true substance (" + ", ".join(SUBSTANCES) + "):")
    for name, per_set in recall.items():
        print(f"  {name}: " + "; ".join(f"{k} " + " ".join(f"{v:.2f}" for v in per.values())
                                         for k, per in per_set.items()))
    print("\nweights (network, head, colour, substance head columns as used):")
    for name, w in weights.items():
        print(f"  {name}: {w}")
    print("\nnetwork vs material head (substance with most mass):")
    for k, a in agreement.items():
        print(f"  {k}: agree on {a['agree']:.3f} of {a['parts']} (right {a['accuracy_when_agree']:.3f} of those); "
              f"where they disagree the network is right {a['disagree_network_right']:.3f}, "
              f"the head {a['disagree_head_right']:.3f}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"records": str(records_path), "aligned": str(args.aligned or ""), "rows": rows,
                                    "weights": weights, "agreement": agreement, "shares": shares,
                                    "recall": recall, "train_prior": train_prior.tolist()}, indent=2))


if __name__ == "__main__":
    main()
