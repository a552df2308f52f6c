"""Per-region evidence records for scoring substance/material rankings offline.

Writes, for a demo database (PHOTOSHAPE_DATA_ROOT), one record per scored region with every piece
of evidence inference has: the material head's probabilities, the classifier's own substance head,
the substance network's part probabilities (raw) and its decision, the part's median CIELAB colour,
the region's share of the image, and the truth (material index in the classifier's order, substance):

  - "validation": the validation training renders' exact material regions (>= 0.5% of the image),
    the network run on each render as the substances stage runs it on an exemplar;
  - "exemplars":  the aligned parts of every aligned pair with demo ground truth, exactly as
    `photoshape eval` scores them (majority ground-truth label under the aligned mask).

Any ranking can then be scored from the JSON without re-running a network:
bench/substance_ceiling.py does that. Nothing here is fit or chosen.

    PHOTOSHAPE_DATA_ROOT=... python bench/fusion_records.py [groundtruth.json] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.classify.substance_train import predict_substances
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import load_groundtruth, newest_groundtruth
from photoshape_flow.pipeline.evaluate import _majority
from photoshape_flow.pipeline.inference import COLOR_SIGMA_RENDERS
from photoshape_flow.pipeline.training import load_material_classifier, training_data
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import SUBSTANCES

sys.path.insert(0, str(Path(__file__).parent))
from ranking_evidence import exemplar_pairs, load_evidence, validation_regions


def _lab(rgb: np.ndarray, mask: np.ndarray) -> list[float] | None:
    lab = median_lab(rgb, mask)
    return None if lab is None else np.asarray(lab, np.float64).round(3).tolist()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("groundtruth", nargs="?", type=Path)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "fusion_records.json")
    args = parser.parse_args()
    settings = get_settings()
    gt_path = args.groundtruth or newest_groundtruth(settings.data_root)
    if gt_path is None:
        sys.exit(f"{settings.data_root}: no demo ground truth; run `photoshape demo` or pass groundtruth.json")
    gt = load_groundtruth(gt_path)
    store = BlobStore(settings.blob_root)
    row, clf = load_material_classifier(settings=settings)
    index = {mid: i for i, mid in enumerate(clf.materials)}
    min_fraction = float((row.config or {}).get("min_region_fraction", 0.005))
    validation: list[dict] = []
    exemplars: list[dict] = []
    with session_scope() as session:
        ev = load_evidence(session, store, settings, clf.materials)
        data = training_data(session, store)
        for number, ids, rgb, regions in validation_regions(data.val[:COLOR_SIGMA_RENDERS], index, min_fraction):
            mat, sub = clf.predict(rgb, [mask for _, mask in regions])
            net = part_substances(ids, predict_substances(ev.network, rgb, ev.net_size), [r[0] for r in regions])
            for k, ((mid, mask), part) in enumerate(zip(regions, net, strict=True)):
                validation.append({
                    "render": number, "fraction": float(mask.mean()), "truth": index[mid],
                    "true_substance": ev.material_substance[mid], "network": part.substance,
                    "network_probs": [float(part.probs.get(s, 0.0)) for s in SUBSTANCES],
                    "head": mat[k].round(6).tolist(), "head_substance": sub[k].round(6).tolist(),
                    "lab": _lab(rgb, mask),
                })
        names = {mat.id: mat.name for mat in session.execute(sa.select(m.Material)).scalars()}
        by_name = {name: mid for mid, name in names.items()}
        for ep in exemplar_pairs(session, store, gt):
            min_pixels = max(16, int(0.0005 * ep.part_map.size))
            items = []
            for part in ep.parts:
                mask = ep.part_map == part.index
                winner = _majority(ep.labels, mask)
                ps = ep.part_substances.get(part.id)
                if winner is None or mask.sum() < min_pixels or ps is None or not ps.observed or not ps.substance:
                    continue
                truth = by_name.get(ep.materials[winner - 1])
                if truth not in index:
                    continue
                items.append((part, mask, ps, index[truth], ep.substances[winner - 1]))
            if not items:
                continue
            mat, sub = clf.predict(ep.image, [i[1] for i in items])
            for k, (part, mask, ps, truth, true_sub) in enumerate(items):
                exemplars.append({
                    "pair": ep.pair.id, "exemplar": ep.exemplar.id, "part": part.id,
                    "fraction": float(mask.mean()), "truth": truth, "true_substance": true_sub,
                    "network": ps.substance, "network_probs": [float((ps.probs or {}).get(s, 0.0)) for s in SUBSTANCES],
                    "head": mat[k].round(6).tolist(), "head_substance": sub[k].round(6).tolist(),
                    "lab": _lab(ep.image, mask),
                })
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "groundtruth": str(gt_path), "classifier": row.id, "materials": clf.materials,
        "material_substances": clf.material_substances, "labs": ev.labs.round(4).tolist(),
        "color_sigma": ev.sigma, "temperature": ev.temperature, "substance_network": ev.network_id,
        "min_region_fraction": min_fraction, "validation": validation, "exemplars": exemplars,
    }))
    print(f"{len(validation)} validation regions, {len(exemplars)} exemplar parts -> {args.out}")


if __name__ == "__main__":
    main()
