"""How much of the classifier's error on exemplars is the alignment, and how much the photos?

Runs the material head alone (no substance weighting) on every ground-truth material region of the
demo exemplars, i.e. with perfect masks, and prints top-1 / top-5, with and without averaging each
region's prediction with its mirror image (`MaterialClassifier.flip`, on in the pipeline). Compare with the validation
renders' mtl@1 / mtl@5 (the classifier row's metrics) and with the aligned parts
(bench/substance_weighting.py, weighting "none"): the first gap is renders vs photos, the second
the fine alignment's masks. The flip-averaged figures are also split by whether the exemplar
shows a shape of the collection (whose training renders the classifier may have seen) or a
held-out shape (new geometry: only look-alikes were rendered).

    PHOTOSHAPE_DATA_ROOT=... python bench/classifier_domain_gap.py [CLASSIFIER_ID]
"""

from __future__ import annotations

import sys

import sqlalchemy as sa

from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import load_groundtruth, newest_groundtruth
from photoshape_flow.pipeline.evaluate import _exemplar_truths, truth_labels
from photoshape_flow.pipeline.training import load_material_classifier
from photoshape_flow.store import BlobStore


def main() -> None:
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    gt_path = newest_groundtruth(settings.data_root)
    if gt_path is None:
        sys.exit(f"{settings.data_root}: no demo ground truth; run `photoshape demo` first")
    gt = load_groundtruth(gt_path)
    classifier_id = int(sys.argv[1]) if len(sys.argv) > 1 else None
    row, clf = load_material_classifier(classifier_id, settings=settings)
    counts = {flip: [0, 0] for flip in (False, True)}
    by_shape = {True: [0, 0, 0], False: [0, 0, 0]}  # in collection -> top-1, top-5, regions (flip-averaged)
    large = [0, 0, 0]  # regions of at least 0.5% of the image, the training examples' minimum (flip-averaged)
    regions = 0
    with session_scope() as session:
        names = dict(session.execute(sa.select(m.Material.id, m.Material.name)).all())
        for exemplar_id, truth in _exemplar_truths(session, gt, None).items():
            exemplar = session.get(m.Exemplar, exemplar_id)
            labels, materials, _ = truth_labels(truth, exemplar)
            image = store.load_image(exemplar.image_blob)[..., :3]
            masks = [(labels == k, materials[k - 1]) for k in range(1, len(materials) + 1)]
            masks = [(mask, name) for mask, name in masks if mask.sum() >= 16]
            if not masks:
                continue
            regions += len(masks)
            for flip in (False, True):
                clf.flip = flip
                probs, _ = clf.predict(image, [mask for mask, _ in masks])
                ranked_all = clf.top_k(probs, None, k=5, weight_by_substance=False)
                for ranked, (mask, name) in zip(ranked_all, masks, strict=True):
                    picked = [names[r.material_id] for r in ranked]
                    counts[flip][0] += picked[0] == name
                    counts[flip][1] += name in picked
                    if flip and mask.sum() >= 0.005 * mask.size:
                        large[0] += picked[0] == name
                        large[1] += name in picked
                        large[2] += 1
                    if flip:
                        by_shape[truth.in_collection][0] += picked[0] == name
                        by_shape[truth.in_collection][1] += name in picked
                        by_shape[truth.in_collection][2] += 1
    metrics = row.metrics or {}
    print(f"classifier {row.name} (id {row.id})")
    print(f"validation renders: mtl@1 {metrics.get('mtl@1')}, mtl@5 {metrics.get('mtl@5')}")
    for flip, (top1, top5) in counts.items():
        print(f"exemplar ground-truth regions ({regions}), {'flip-averaged' if flip else 'single view'}: "
              f"top-1 {top1 / regions:.3f}, top-5 {top5 / regions:.3f}")
    if large[2]:
        print(f"  flip-averaged, regions of at least 0.5% of the image ({large[2]}): "
              f"top-1 {large[0] / large[2]:.3f}, top-5 {large[1] / large[2]:.3f}")
    for in_collection, (top1, top5, n) in by_shape.items():
        if n:
            print(f"  flip-averaged, exemplars of {'collection' if in_collection else 'held-out'} shapes ({n}): "
                  f"top-1 {top1 / n:.3f}, top-5 {top5 / n:.3f}")


if __name__ == "__main__":
    main()
