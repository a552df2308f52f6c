"""Does the material classifier read photo-like renders better with each photo's own BatchNorm statistics?

    python -m experiments.bn_adaptation.run --renders 150 --priors none,64,16,4,1,0

`classify.bn_adapt` mixes every BatchNorm layer's training statistics with the input photo's
(the training set counts as N samples, the photo as one). Here N is chosen the way the fit's
weights are: on the collection's validation renders (val shapes, val envmaps, library materials),
each degraded like an exemplar at the exemplars' size (`networks.validation_photos.as_photo`) with its part
map misaligned as fine alignment errs, never on exemplars or evaluation worlds. For each prior:
per region the material head's top-1 and top-5 over the enabled materials, the log-loss of the
true material, the substance head's top-1 and the substance network's part-level top-1 (its own
BatchNorm adapted with the same prior); `clean` repeats it on the undegraded render (the
classifier's own domain: adaptation must not cost much there). Paired 95% bootstrap intervals
over renders against no adaptation.

Read-only. Output: `<data root>/experiments/bn_adaptation/results.json`.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
import sqlalchemy as sa

from experiments.common import results_dir
from photoshape_flow.classify.substance_configs import read_side_of
from photoshape_flow.classify.substance_recognition import substance_map
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.networks.classifiers import load_material_classifier, load_substance_network
from photoshape_flow.recognition.bn_prior import PhotoCase, photo_cases
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import SUBSTANCE_LABELS


def score(model: Any, items: list[PhotoCase], enabled: set[int],
          substance_of: dict[int, str]) -> dict[str, np.ndarray]:
    """Per render: sums of top-1, top-5, log-loss and substance top-1 over its regions, and region counts."""
    columns = np.array([i + 1 for i, mid in enumerate(model.materials) if mid in enabled])
    ids = np.array(model.materials)[columns - 1]
    sums = {k: [] for k in ("top1", "top5", "logloss", "substance", "regions")}
    for item in items:
        mats, subs = model.predict(item.image, list(item.masks))
        probs = mats[:, columns]
        probs = probs / probs.sum(1, keepdims=True)
        order = np.argsort(-probs, axis=1)
        t1 = t5 = ll = sb = 0.0
        for k, true in enumerate(item.truth):
            where = np.nonzero(ids == true)[0]
            if not len(where):
                continue
            ranks = ids[order[k]]
            t1 += float(ranks[0] == true)
            t5 += float(true in ranks[:5])
            ll += -float(np.log(max(probs[k, where[0]], 1e-9)))
            sb += float(SUBSTANCE_LABELS[int(np.argmax(subs[k][1:])) + 1] == substance_of[true])
        for key, value in zip(sums, (t1, t5, ll, sb, float(len(item.truth))), strict=True):
            sums[key].append(value)
    return {k: np.array(v) for k, v in sums.items()}


def score_network(network: Any, size: int, items: list[PhotoCase], prior: float | None,
                  substance_of: dict[int, str]) -> dict[str, np.ndarray]:
    """Per render: the substance network's part-level top-1 (mean probability in the mask) and region count."""
    hits, regions = [], []
    for item in items:
        labels = np.zeros(item.image.shape[:2], np.int32)
        for k, mask in enumerate(item.masks, start=1):
            labels[mask] = k
        probs = substance_map(network, item.image, labels, size, bn_prior=prior)
        good = 0.0
        for mask, true in zip(item.masks, item.truth, strict=True):
            mean = probs[1:, mask].mean(1)
            good += float(SUBSTANCE_LABELS[int(np.argmax(mean)) + 1] == substance_of[true])
        hits.append(good)
        regions.append(float(len(item.truth)))
    return {"network": np.array(hits), "regions": np.array(regions)}


def paired(a: dict[str, np.ndarray], b: dict[str, np.ndarray], key: str, rng: np.random.Generator) -> list[float]:
    """b - a of the per-region mean of `key`, with a 95% bootstrap interval over renders."""
    n = len(a["regions"])
    draws = rng.integers(0, n, (2000, n))
    diff = [(b[key][d].sum() - a[key][d].sum()) / a["regions"][d].sum() for d in draws]
    point = (b[key].sum() - a[key].sum()) / a["regions"].sum()
    return [round(point, 4), round(float(np.percentile(diff, 2.5)), 4), round(float(np.percentile(diff, 97.5)), 4)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--renders", type=int, default=150)
    parser.add_argument("--priors", default="none,64,16,4,1,0")
    parser.add_argument("--conditions", default="deg,clean")
    args = parser.parse_args(argv)
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    row, model = load_material_classifier(None, settings)
    with session_scope(settings.resolved_database_url) as session:
        enabled = set(session.execute(sa.select(m.Material.id).where(m.Material.enabled)).scalars())
        substance_of = dict(session.execute(sa.select(m.Material.id, m.Material.substance)).all())
        conditions = {c: photo_cases(session, store, settings, args.renders, degrade=c == "deg")
                      for c in args.conditions.split(",")}
    priors = [None if p == "none" else float(p) for p in args.priors.split(",")]
    with session_scope(settings.resolved_database_url) as session:
        newest = max(n for n in session.execute(sa.select(m.PartSubstance.classifier_id).distinct()).scalars() if n)
        net_row = session.get(m.Classifier, newest)
        network = load_substance_network(net_row, store, "cpu")
        net_size = read_side_of(net_row.config) or 128
    results: dict[str, Any] = {"classifier": row.id, "renders": args.renders, "conditions": {}}
    for condition, items in conditions.items():
        per_prior = {}
        for prior in priors:
            model.bn_prior = prior
            per_prior[str(prior)] = {**score(model, items, enabled, substance_of),
                                     **score_network(network, net_size, items, prior, substance_of)}
        base = per_prior[str(priors[0])]
        table = {}
        for prior, s in per_prior.items():
            regions = s["regions"].sum()
            rng = np.random.default_rng(0)
            table[prior] = {"top1": round(s["top1"].sum() / regions, 4), "top5": round(s["top5"].sum() / regions, 4),
                            "logloss": round(s["logloss"].sum() / regions, 4),
                            "substance": round(s["substance"].sum() / regions, 4),
                            "network": round(s["network"].sum() / regions, 4),
                            "d_network": paired(base, s, "network", rng),
                            "d_top1": paired(base, s, "top1", rng), "d_substance": paired(base, s, "substance", rng),
                            "d_logloss": paired(base, s, "logloss", rng)}
            print(condition, prior, f"renders {len(items)} regions {int(regions)}", table[prior], flush=True)
        results["conditions"][condition] = table
    out = results_dir(settings, "bn_adaptation")
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
