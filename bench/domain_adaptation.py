"""Does re-estimating the classifier's BatchNorm statistics on the exemplars (AdaBN) close its photo gap?

Collects the inputs inference classifies (each observed aligned part of each pair, with its mask; no
label is read), re-estimates the material classifier's BatchNorm statistics on them
(`classify.adapt.adapt_batchnorm`), and scores the material head alone, before and after, on
  - the exemplars' ground-truth material regions (perfect masks; what bench/classifier_domain_gap.py
    reports), flip-averaged as the pipeline predicts, and
  - the validation renders' exact material regions (the domain the statistics came from: what the
    adaptation costs there).

    PHOTOSHAPE_DATA_ROOT=... python bench/domain_adaptation.py [CLASSIFIER_ID]
"""

from __future__ import annotations

import copy
import sys

import numpy as np
import sqlalchemy as sa
import torch

from photoshape_flow.classify.dataset import find_regions, load_label_map, load_rgb
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import load_groundtruth, newest_groundtruth
from photoshape_flow.pipeline.evaluate import _exemplar_truths, truth_labels
from photoshape_flow.pipeline.inference import ALIGNMENT_METHOD, _load_part_map
from photoshape_flow.pipeline.training import load_material_classifier, training_data
from photoshape_flow.store import BlobStore


@torch.no_grad()
def adapt_batchnorm(model: torch.nn.Module, batches, device="cpu") -> int:
    """AdaBN: every BatchNorm layer's running mean and variance re-estimated as the average over `batches`."""
    layers = [mod for mod in model.modules() if isinstance(mod, torch.nn.modules.batchnorm._BatchNorm)]
    model.eval()
    for layer in layers:
        layer.reset_running_stats()
        layer.momentum = None  # cumulative average over all batches
        layer.train()
    seen = 0
    for batch in batches:
        if len(batch) > 1:
            model(batch.to(device))
            seen += len(batch)
    for layer in layers:
        layer.momentum = 0.1
        layer.eval()
    return seen


def shuffled_batches(inputs: torch.Tensor, batch_size: int, seed: int = 0):
    order = torch.randperm(len(inputs), generator=torch.Generator().manual_seed(seed))
    for start in range(0, len(order), batch_size):
        yield inputs[order[start:start + batch_size]]


def exemplar_part_inputs(session, store, clf) -> torch.Tensor:
    """The classifier's inputs for every part inference classifies (its observed-part rule), no labels read."""
    tensors = []
    rows = session.execute(
        sa.select(m.Pair, m.Alignment).join(m.Alignment, sa.and_(m.Alignment.pair_id == m.Pair.id,
                                                                 m.Alignment.method == ALIGNMENT_METHOD))
        .where(m.Alignment.status == "ok", ~m.Pair.exclude).order_by(m.Pair.id)
    ).all()
    for pair, alignment in rows:
        exemplar = session.get(m.Exemplar, pair.exemplar_id)
        image = store.load_image(exemplar.image_blob)[..., :3]
        part_map = _load_part_map(store, alignment, image.shape[:2])
        substances = {ps.part_id: ps for ps in session.execute(
            sa.select(m.PartSubstance).where(m.PartSubstance.pair_id == pair.id)).scalars()}
        min_pixels = max(16, int(0.0005 * part_map.size))  # as inference.infer_pair
        masks = []
        for part in session.execute(sa.select(m.Part).where(m.Part.shape_id == pair.shape_id)).scalars():
            mask = part_map == part.index
            ps = substances.get(part.id)
            if mask.sum() >= min_pixels and (ps is None or ps.observed):
                masks.append(mask)
        if masks:
            tensors.append(clf.inputs(image, masks))
    return torch.cat(tensors)


def score(clf, cases) -> tuple[float, float, int]:
    top1 = top5 = n = 0
    for image, masks, labels in cases:
        probs, _ = clf.predict(image, masks)
        for ranked, label in zip(clf.top_k(probs, None, k=5, weight_by_substance=False), labels, strict=True):
            picked = [r.material_id for r in ranked]
            top1 += picked[0] == label
            top5 += label in picked
            n += 1
    return top1 / max(n, 1), top5 / max(n, 1), n


def substance_network(session, store, cases) -> None:
    """AdaBN for the substance segmentation network, adapted on the exemplar images (both flips)."""
    import cv2

    from photoshape_flow.classify.substance_train import (
        _to_tensor,
        checkpoint_from_bytes,
        load_model,
        predict_substances,
    )
    from photoshape_flow.vocab import SUBSTANCE_LABELS

    row = session.execute(sa.select(m.Classifier).where(m.Classifier.kind == "substance", m.Classifier.status == "ok")
                          .order_by(m.Classifier.id.desc()).limit(1)).scalar_one_or_none()
    if row is None:
        print("no substance network")
        return
    size = int((row.config or {}).get("size") or 128)
    model = load_model(checkpoint_from_bytes(store.read_bytes(row.checkpoint_blob)))

    def accuracy(net) -> float:
        right = total = 0
        for image, labels, subs in cases:
            pred = predict_substances(net, image, size).argmax(0)
            fg = labels > 0
            truth = np.array([0] + [SUBSTANCE_LABELS.index(s) for s in subs])[labels]
            right += int((pred[fg] == truth[fg]).sum())
            total += int(fg.sum())
        return right / max(total, 1)

    before = accuracy(model)
    views = []
    for image, _, _ in cases:
        small = cv2.resize(image.astype(np.float32) / 255.0, (size, size), interpolation=cv2.INTER_AREA)
        views += [small, np.ascontiguousarray(small[:, ::-1])]
    seen = adapt_batchnorm(model, shuffled_batches(_to_tensor(views), 16, seed=0))
    print(f"substance network {row.name} (id {row.id}), exemplar GT foreground pixel accuracy: "
          f"as trained {before:.3f}, AdaBN on {seen} exemplar views {accuracy(model):.3f}")


def main() -> None:
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    gt_path = newest_groundtruth(settings.data_root)
    if gt_path is None:
        sys.exit(f"{settings.data_root}: no demo ground truth; run `photoshape demo` first")
    gt = load_groundtruth(gt_path)
    torch.manual_seed(0)
    row, clf = load_material_classifier(int(sys.argv[1]) if len(sys.argv) > 1 else None, settings=settings)
    exemplar_cases, val_cases, substance_cases = [], [], []
    with session_scope() as session:
        ids = {name: mid for mid, name in session.execute(sa.select(m.Material.id, m.Material.name)).all()}
        for exemplar_id, truth in _exemplar_truths(session, gt, None).items():
            exemplar = session.get(m.Exemplar, exemplar_id)
            labels, materials, _ = truth_labels(truth, exemplar)
            image = store.load_image(exemplar.image_blob)[..., :3]
            regions = [(labels == k, ids[materials[k - 1]]) for k in range(1, len(materials) + 1)]
            regions = [(mask, mid) for mask, mid in regions if mask.sum() >= 16]
            substance_cases.append((image, labels, truth_labels(truth, exemplar)[2]))
            if regions:
                exemplar_cases.append((image, [r[0] for r in regions], [r[1] for r in regions]))
        data = training_data(session, store)
        items = data.val[:300]
        by_item: dict[int, list[int]] = {}
        for ex in find_regions(items, clf.materials, dict(zip(clf.materials, clf.material_substances, strict=True))):
            by_item.setdefault(ex.item, []).append(ex.material_id)
        for index, mids in sorted(by_item.items()):
            mat_map = load_label_map(items[index].material_map)
            val_cases.append((load_rgb(items[index].image), [mat_map == mid for mid in mids], mids))
        inputs = exemplar_part_inputs(session, store, clf)
    print(f"classifier {row.name} (id {row.id}); {len(inputs)} aligned part inputs to adapt on")
    before_ex, before_val = score(clf, exemplar_cases), score(clf, val_cases)
    adapted = copy.deepcopy(clf)
    seen = adapt_batchnorm(adapted.model, shuffled_batches(inputs, 64, seed=0))
    after_ex, after_val = score(adapted, exemplar_cases), score(adapted, val_cases)
    print("| classifier | exemplar GT regions top-1 / top-5 | validation render regions top-1 / top-5 |")
    print("|---|---|---|")
    for name, ex, val in (("as trained", before_ex, before_val), (f"AdaBN on {seen} part inputs", after_ex, after_val)):
        print(f"| {name} | {ex[0]:.3f} / {ex[1]:.3f} ({ex[2]}) | {val[0]:.3f} / {val[1]:.3f} ({val[2]}) |")
    with session_scope() as session:
        substance_network(session, store, substance_cases)


if __name__ == "__main__":
    main()
