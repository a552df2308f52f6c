"""Material top-1 of each factor of ours' product, and of their products, from the same records.

Ours ranks a part's materials by head x substance network x colour likelihood (`classify.ranking`).
Whether a better material head (a pretrained backbone) can lift ours depends on what the other two
factors already say: this scores every subset of the three on the records of
`experiments.substance_ceiling.records` (validation renders' exact regions, exemplars' aligned parts),
plain argmax of the product (no substance-first rule, no small-part rule), the network's
probabilities tempered by its stored part-level temperature as inference tempers them. Top-1 is
over the classifier's materials, with a 95% interval resampling exemplars (renders for validation).

With photo-like records (`records --photo-like N`: validation renders degraded like exemplars, part
maps misaligned) the head's exponent in the full product, head^a x network x colour, is chosen there
on a grid (`EXPONENTS`, by top-1, ties to the larger a); every a is also scored on the exemplars,
which are measured, never chosen on.

    PHOTOSHAPE_DATA_ROOT=... python -m experiments.substance_ceiling.materials [RECORDS] [--label NAME]

Appends its table to <data root>/experiments/substance_ceiling/materials.json under NAME.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

from photoshape_flow.classify.color_prior import color_likelihood
from photoshape_flow.classify.substance_calibration import temper
from photoshape_flow.config import get_settings
from photoshape_flow.vocab import SUBSTANCES

from ..common import interval, results_dir

FACTORS = ("head", "network", "colour")
EXPONENTS = (0.0, 0.1, 0.25, 0.5, 0.75, 1.0)  # the head's exponent in the full product


def factor_matrix(r: dict, labs: np.ndarray, sigma: float | None, column: np.ndarray,
                  temperature: float | None) -> np.ndarray:
    """(3, M): each factor's weight per material of one record (1 where a factor is unknown)."""
    head = np.maximum(np.asarray(r["head"][1:], np.float64), 1e-12)
    tempered = temper(dict(zip(SUBSTANCES, r["network_probs"], strict=True)), temperature)
    by_substance = np.array([max(tempered.get(s, 0.0), 1e-12) for s in SUBSTANCES])
    network = by_substance[column] if tempered else np.ones(len(head))
    known = r.get("lab") is not None and sigma is not None
    colour = np.maximum(color_likelihood(r["lab"], labs, sigma), 1e-300) if known else np.ones(len(head))
    return np.stack([head, network, colour])


def score(records: list[dict], data: dict, column: np.ndarray, group_key: str) -> dict[str, list[float] | None]:
    """Top-1 [mean, low, high] of every non-empty subset of `FACTORS`, and of the full product with the
    head raised to each of `EXPONENTS` (keys ``head^a x network x colour``)."""
    labs, sigma, temperature = np.asarray(data["labs"], np.float64), data["color_sigma"], data["temperature"]
    mats = [factor_matrix(r, labs, sigma, column, temperature) for r in records]
    truth = np.array([r["truth"] for r in records])
    groups = np.array([int(r.get(group_key, 0)) for r in records])
    out: dict[str, list[float] | None] = {}
    rng = np.random.default_rng(0)

    def top1(weights: np.ndarray) -> list[float] | None:
        picks = np.array([int(np.argmax(np.prod(m ** weights[:, None], axis=0))) for m in mats])
        return interval((picks == truth).astype(float), groups, rng)

    for k in range(1, len(FACTORS) + 1):
        for subset in itertools.combinations(range(len(FACTORS)), k):
            out[" x ".join(FACTORS[i] for i in subset)] = top1(np.isin(np.arange(3), subset).astype(float))
    for a in EXPONENTS:
        out[f"head^{a} x network x colour"] = top1(np.array([a, 1.0, 1.0]))
    return out


def chosen_exponent(photo_like: dict[str, list[float] | None]) -> float:
    """The head exponent with the best top-1 on the photo-like validation renders (ties: the larger)."""
    return max(EXPONENTS, key=lambda a: ((photo_like[f"head^{a} x network x colour"] or [0.0])[0], a))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="?", type=Path)
    parser.add_argument("--label", default="default", help="the classifier's name in the output")
    args = parser.parse_args()
    folder = results_dir(get_settings(), "substance_ceiling")
    data = json.loads((args.records or folder / "records.json").read_text())
    column = np.array([SUBSTANCES.index(s) for s in data["material_substances"]])
    table: dict = {"classifier": data["classifier"],
                   "validation": score(data["validation"], data, column, "render"),
                   "exemplars": score(data["exemplars"], data, column, "exemplar")}
    sets = ["validation", "exemplars"]
    if data.get("photo_like"):
        table["photo_like"] = score(data["photo_like"], data, column, "render")
        table["chosen_exponent"] = chosen_exponent(table["photo_like"])
        sets.insert(1, "photo_like")
    out = folder / "materials.json"
    results = json.loads(out.read_text()) if out.exists() else {}
    results[args.label] = table
    out.write_text(json.dumps(results, indent=1))
    print(f"{args.label} (classifier {data['classifier']}; regions: "
          + ", ".join(f"{name} {len(data[name])}" for name in sets) + "): top-1 [mean, 2.5%, 97.5%]"
          + (f"; head exponent chosen on photo-like renders: {table['chosen_exponent']}" if "chosen_exponent" in table
             else ""))
    for name in table["validation"]:
        print(f"  {name:32s} " + "  ".join(f"{where} {table[where][name]}" for where in sets))


if __name__ == "__main__":
    main()
