"""Material accuracy of the `fit` stage against the classifier it starts from, per fit variant.

    python -m experiments.fit_by_rendering.run --profile tiny            # the defaults and three ablations
    python -m experiments.fit_by_rendering.run --variant blur0=fit.blur=0 --variant default=

Needs a demo data root that went through inference (`photoshape demo --size tiny`); each variant
re-runs `fit` with its overrides (its rows replace the previous variant's) and scores the inference
stage's methods against the demo's ground truth, as `photoshape eval --stage inference` does.
Writes `<data root>/experiments/fit_by_rendering/results.json`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from experiments.common import results_dir
from photoshape_flow.config import get_settings
from photoshape_flow.fitting.fit import run_fit
from photoshape_flow.method_keys import CLASSIFIER, FIT, method_of
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.scoring.evaluate import run_evaluation

VARIANTS = {
    "default": [],  # weights and temperature fitted on validation renders (D34)
    "hand-set": ["fit.calibration_cases=0"],  # the profile's weights (D32), temperature 1
    "blur0": ["fit.blur=0"],
    "no-exposure-search": ["fit.exposure_stops=0"],
    "no-prior": ["fit.prior_weight=0"],
}
FIGURES = ("material_top1", "material_top5", "substance_accuracy")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="tiny")
    parser.add_argument("--groundtruth", type=Path, default=None, help="default: the demo's under the data root")
    parser.add_argument("--variant", action="append", default=[],
                        help="name=override,override (repeatable; default: the built-in variants)")
    args = parser.parse_args()
    settings = get_settings()
    groundtruth = args.groundtruth or sorted(Path(settings.data_root).glob("demo/*/groundtruth.json"))[-1]
    variants = ({name: [o for o in rest.split(",") if o] for name, _, rest in (v.partition("=") for v in args.variant)}
                if args.variant else VARIANTS)
    results = {}
    for name, overrides in variants.items():
        cfg = resolve_profile(args.profile, overrides).profile.fit
        start = time.perf_counter()
        summary = run_fit(cfg, settings=settings)
        seconds = time.perf_counter() - start
        _, metrics = run_evaluation(groundtruth, f"fit-{name}", stages=["inference"], settings=settings,
                                    rerender_max_pairs=0)
        figures = {f"{x.method} {x.metric}": [round(x.value, 4) if x.value is not None else None, x.count]
                   for x in metrics if x.metric in FIGURES and method_of(x.method) in (FIT, CLASSIFIER)}
        results[name] = {"overrides": overrides, "pairs": summary.pairs_done, "seconds": round(seconds, 1),
                         "weights": summary.weights, "figures": figures}
        print(name, overrides, f"{summary.pairs_done} pairs in {seconds:.1f} s", summary.weights)
        for key, (value, count) in sorted(figures.items()):
            print(f"  {key:40s} {value} ({count} parts)")
    out = results_dir(settings, "fit_by_rendering")
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
