"""Which substance confidence should weight the classifier's material probabilities (section 5.2.4)?

Measured on a demo database after `photoshape demo` (PHOTOSHAPE_DATA_ROOT pointing at it): per-part
material top-1/top-5 against the ground truth for
  - none:        the material head alone,
  - network:     x the substance segmentation network's confidence (PartSubstance.probs; the default),
  - head:        x the classifier's own substance head,
  - both:        x the product of the two;
and the substance accuracy of each ranking's top-1 material, next to the substance network's own
argmax (what the no-classifier baseline picks). Prints a table and writes bench/results/substance_weighting.json.

    python bench/substance_weighting.py [groundtruth.json]
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.assignment import substance_vector
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import load_groundtruth, newest_groundtruth
from photoshape_flow.pipeline.evaluate import _exemplar_truths, _majority, _part_map, truth_labels
from photoshape_flow.pipeline.training import load_material_classifier
from photoshape_flow.store import BlobStore


def main() -> None:
    settings = get_settings()
    gt_path = Path(sys.argv[1]) if len(sys.argv) > 1 else newest_groundtruth(settings.data_root)
    if gt_path is None:
        sys.exit(f"{settings.data_root}: no demo ground truth; run `photoshape demo` or pass groundtruth.json")
    gt = load_groundtruth(gt_path)
    store = BlobStore(settings.blob_root)
    row, clf = load_material_classifier(settings=settings)
    names: dict[int, str] = {}
    hits: dict[str, list[tuple[float, float]]] = defaultdict(list)
    with session_scope() as session:
        names = dict(session.execute(sa.select(m.Material.id, m.Material.name)).all())
        truths = _exemplar_truths(session, gt, None)
        pairs = session.execute(
            sa.select(m.Pair, m.Alignment).join(m.Alignment, m.Alignment.pair_id == m.Pair.id)
            .where(m.Alignment.status == "ok", m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)
        ).all()
        for pair, alignment in pairs:
            exemplar = session.get(m.Exemplar, pair.exemplar_id)
            labels, mats, true_subs = truth_labels(truths[exemplar.id], exemplar)
            part_map = _part_map(store, alignment, labels.shape[0])
            image = store.load_image(exemplar.image_blob)[..., :3]
            subs = {ps.part_id: ps for ps in session.execute(
                sa.select(m.PartSubstance).where(m.PartSubstance.pair_id == pair.id)).scalars()}
            parts = session.execute(sa.select(m.Part).where(m.Part.shape_id == pair.shape_id)).scalars().all()
            items = []
            for part in parts:
                mask = part_map == part.index
                winner = _majority(labels, mask)
                if winner is None or mask.sum() < 16 or part.id not in subs or not subs[part.id].observed:
                    continue
                items.append((mask, mats[winner - 1], substance_vector(subs[part.id].probs),
                              true_subs[winner - 1], subs[part.id].substance))
            if not items:
                continue
            mat_probs, head_probs = clf.predict(image, [i[0] for i in items])
            for k, (_, truth, network, true_sub, network_sub) in enumerate(items):
                hits["network argmax (substance only)"].append((float("nan"), float("nan"),
                                                                float(network_sub == true_sub)))
                variants = {"none": None, "network": network, "head": head_probs[k],
                            "both": network * head_probs[k]}
                for name, weights in variants.items():
                    ranked = clf.top_k(mat_probs[k:k + 1], None if weights is None else weights[None], k=5,
                                       weight_by_substance=weights is not None)[0]
                    picked = [names[r.material_id] for r in ranked]
                    hits[name].append((float(picked[:1] == [truth]), float(truth in picked),
                                       float(ranked[0].substance == true_sub)))
    result = {
        name: {"material_top1": float(np.mean([h[0] for h in v])), "material_top5": float(np.mean([h[1] for h in v])),
               "substance_accuracy": float(np.mean([h[2] for h in v])), "parts": len(v)}
        for name, v in hits.items()
    }
    print(f"classifier {row.name} on {gt_path}")
    print("| weighting | top-1 | top-5 | substance acc. | parts |\n|---|---:|---:|---:|---:|")
    for name, r in result.items():
        print(f"| {name} | {r['material_top1']:.3f} | {r['material_top5']:.3f} | {r['substance_accuracy']:.3f} "
              f"| {r['parts']} |")
    out = Path(__file__).parent / "results" / "substance_weighting.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"groundtruth": str(gt_path), "classifier": row.name, "results": result}, indent=2))


if __name__ == "__main__":
    main()
