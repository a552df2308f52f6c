"""Material classifiers on the photo-like validation renders, paired: the validation side of D65.

    PHOTOSHAPE_DATA_ROOT=/work/demo-b python -m experiments.substance_draw.run --classifier 2 --classifier 3 \\
        [--kinds training,bootstrap] [--renders 200]

Each classifier reads the same photo-like validation renders (`recognition.bn_prior.photo_cases`:
shapes and envmaps no network trained on, degraded like exemplars, part maps misaligned); the
`bootstrap` kind alone gives renders whose substances were drawn without the substance network.
Prints material top-1 / top-5, the substance of the top material, recall per true substance, and
the difference of the last classifier minus the first with a 95% bootstrap interval over renders.
Writes `<data root>/experiments/substance_draw/validation.json`.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from typing import Any

import numpy as np

from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.devices import set_torch_threads
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.recognition.bn_prior import photo_cases
from photoshape_flow.recognition.material_sets import material_set
from photoshape_flow.store import BlobStore

from ..common import HIT_COLUMNS, interval, region_hits, results_dir

# what is reported -> the column of `region_hits`' rows
COLUMNS = {"top1": HIT_COLUMNS.index("top1"), "top5": HIT_COLUMNS.index("top5"),
           "substance": HIT_COLUMNS.index("substance_top")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--classifier", type=int, action="append", required=True, help="material classifier id")
    parser.add_argument("--kinds", default="training,bootstrap", help="rounds whose validation renders are read")
    parser.add_argument("--renders", type=int, default=200)
    args = parser.parse_args()
    settings = get_settings()
    set_torch_threads(settings.torch_threads)
    store = BlobStore(settings.blob_root)
    with session_scope(settings.resolved_database_url) as session:
        cases = photo_cases(session, store, settings, args.renders, kinds=tuple(args.kinds.split(",")))
        materials = material_set(session)
    out: dict[str, Any] = {"kinds": args.kinds, "renders": len(cases)}
    hits = {}
    for classifier_id in args.classifier:
        _row, model = load_material_classifier(classifier_id, settings)
        rows = region_hits(model, cases, materials.ids)
        substance_of = dict(zip(model.materials, model.material_substances, strict=True))
        recall: dict[str, list[float]] = defaultdict(list)
        for row in rows:
            recall[substance_of[int(row[1])]].append(row[COLUMNS["substance"]])
        hits[classifier_id] = rows
        out[str(classifier_id)] = {
            "regions": len(rows), **{k: round(float(rows[:, j].mean()), 4) for k, j in COLUMNS.items()},
            "recall": {s: [round(float(np.mean(v)), 3), len(v)] for s, v in sorted(recall.items())},
            "hits": rows.tolist()}
        print(classifier_id, {k: v for k, v in out[str(classifier_id)].items() if k != "hits"}, flush=True)
    first, last = args.classifier[0], args.classifier[-1]
    if first != last:
        a, b = hits[first], hits[last]  # the same regions in the same order: paired by row
        for name, column in COLUMNS.items():
            d, low, high = interval(b[:, column] - a[:, column], a[:, 0], np.random.default_rng(0), draws=2000)
            out[f"{last}-{first}.{name}"] = [d, low, high]
            print(f"{name}: {last} minus {first} {d:+.3f} ({low:+.3f}, {high:+.3f}) over {len(a)} regions, "
                  f"{len(cases)} renders")
    target = results_dir(settings, "substance_draw") / "validation.json"
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(out))
    print(f"-> {target}")


if __name__ == "__main__":
    main()
