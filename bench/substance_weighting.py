"""Which evidence should weight the classifier's material probabilities (section 5.2.4 and beyond)?

Measured on a demo database after `photoshape demo` (PHOTOSHAPE_DATA_ROOT pointing at it): per-part
material top-1/top-5 against the ground truth for
  - none:             the material head alone,
  - network:          x the substance segmentation network's confidence (PartSubstance.probs; the paper),
  - head:             x the classifier's own substance head,
  - both:             x the product of the two,
  - network + colour: x the network's confidence x the colour likelihood of `classify.color_prior`
                      (run 4's ranking), with sigma fit on the validation renders, and at
                      sigma / 2 and 2 sigma to show how sensitive it is,
  - calibrated:       the network's confidence tempered by its part-level temperature
                      (`classify.substance_calibration`, fit on the bootstrap validation renders),
                      alone and x colour (the pipeline's default since inference-4),
  - colour only:      the colour likelihood alone (the colour-matching baseline's ranking),
  - sqrt(material head) x network x colour: the material head tempered (T = 2), a diagnostic of
                      whether the material head is over-confident against the other two,
and the substance accuracy of each ranking's top-1 material, next to the substance network's own
argmax (what the no-classifier baseline picks); on the exemplars also inference-7 and inference-8
(the pipeline since session 9; below the classifier's smallest training region: no head, and for
inference-8 the network's own substance), each split by part size. First, on the validation renders (where sigma and
the temperature are fit, and where a ranking may be chosen without touching the exemplars): the
rankings on the renders' exact material regions.
Prints tables and writes bench/results/substance_weighting.json.

    python bench/substance_weighting.py [groundtruth.json]
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.assignment import median_lab, substance_vector
from photoshape_flow.classify.color_prior import (
    color_likelihood,
    fit_color_sigma,
    material_lab_matrix,
    region_color_distances,
)
from photoshape_flow.classify.infer import substance_first_order
from photoshape_flow.classify.substance_calibration import temper
from photoshape_flow.classify.substance_train import checkpoint_from_bytes, load_model, predict_substances
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import load_groundtruth, newest_groundtruth
from photoshape_flow.pipeline.evaluate import _majority
from photoshape_flow.pipeline.inference import COLOR_SIGMA_RENDERS, material_lab
from photoshape_flow.pipeline.substances import substance_temperature
from photoshape_flow.pipeline.training import load_material_classifier, training_data
from photoshape_flow.store import BlobStore

sys.path.insert(0, str(Path(__file__).parent))
from ranking_evidence import exemplar_pairs, validation_regions


def _summary(hits: dict[str, list[tuple[float, float, float]]]) -> dict[str, dict[str, float]]:
    return {
        name: {"material_top1": float(np.mean([h[0] for h in v])), "material_top5": float(np.mean([h[1] for h in v])),
               "substance_accuracy": float(np.nanmean([h[2] for h in v])), "parts": len(v)}
        for name, v in hits.items()
    }


def _print(title: str, result: dict[str, dict[str, float]]) -> None:
    print(f"\n{title}\n| ranking | top-1 | top-5 | substance acc. | regions |\n|---|---:|---:|---:|---:|")
    for name, r in result.items():
        print(f"| {name} | {r['material_top1']:.3f} | {r['material_top5']:.3f} | {r['substance_accuracy']:.3f} "
              f"| {r['parts']} |")


def validation_renders(clf, data, labs: np.ndarray, sigma: float, network: tuple, temperature: float | None,
                       material_substance: dict[int, str]) -> dict[str, dict[str, float]]:
    """Every ranking on the validation renders' exact material regions: where a ranking may be chosen.

    The substance network's confidence for a region is `part_substances` over the region, as for an
    aligned part; "colour within substance" renormalises the colour likelihood inside each substance
    (colour picks the material, never the substance), a variant considered and not adopted.
    """
    from photoshape_flow.classify.substance_parts import part_substances

    model, size = network
    index = {mid: i for i, mid in enumerate(clf.materials)}
    subs = np.array(clf.material_substances)
    hits: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
    for _, ids, rgb, regions in validation_regions(data.val[:COLOR_SIGMA_RENDERS], index):
        probs, _ = clf.predict(rgb, [mask for _, mask in regions])
        net = part_substances(ids, predict_substances(model, rgb, size), [r[0] for r in regions])
        for k, ((mid, mask), part) in enumerate(zip(regions, net, strict=True)):
            true_sub = material_substance[mid]
            raw, calibrated = substance_vector(part.probs), substance_vector(temper(part.probs, temperature))
            colour = color_likelihood(median_lab(rgb, mask), labs, sigma)
            within = colour.copy()
            for name in set(subs.tolist()):
                within[subs == name] /= colour[subs == name].sum()
            hits["network argmax (substance only)"].append(
                (float("nan"), float("nan"), float(part.substance == true_sub)))
            variants = {"none": (None, None), "colour": (None, colour), "network": (raw, None),
                        "calibrated network": (calibrated, None), "network + colour": (raw, colour),
                        "calibrated network + colour (pipeline)": (calibrated, colour),
                        "calibrated network + colour within substance": (calibrated, within)}
            for name, (weights, colours) in variants.items():
                ranked = clf.top_k(probs[k:k + 1], None if weights is None else weights[None], k=5,
                                   weight_by_substance=weights is not None,
                                   color_weights=None if colours is None else colours[None])[0]
                picked = [r.material_id for r in ranked]
                hits[name].append(
                    (float(picked[0] == mid), float(mid in picked), float(ranked[0].substance == true_sub)))
            for name, colours in (("calibrated network + colour, substance by marginal", colour),
                                  ("calibrated network + colour within substance, substance by marginal", within)):
                scores = clf.scores(probs[k:k + 1], calibrated[None], colours[None])[0]
                order = substance_first_order(scores, subs)[:5]
                best = subs[order[0]]
                picked = [clf.materials[i] for i in order]
                hits[name].append((float(picked[0] == mid), float(mid in picked), float(best == true_sub)))
    return _summary(hits)


def main() -> None:
    settings = get_settings()
    gt_path = Path(sys.argv[1]) if len(sys.argv) > 1 else newest_groundtruth(settings.data_root)
    if gt_path is None:
        sys.exit(f"{settings.data_root}: no demo ground truth; run `photoshape demo` or pass groundtruth.json")
    gt = load_groundtruth(gt_path)
    store = BlobStore(settings.blob_root)
    row, clf = load_material_classifier(settings=settings)
    hits: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
    with session_scope() as session:
        materials = session.execute(sa.select(m.Material)).scalars().all()
        names = {mat.id: mat.name for mat in materials}
        mat_labs = {mat.id: lab for mat in materials if (lab := material_lab(mat, store)) is not None}
        labs = material_lab_matrix(clf.materials, mat_labs)
        data = training_data(session, store)
        distances = region_color_distances(data.val, mat_labs, limit=COLOR_SIGMA_RENDERS)
        sigma = fit_color_sigma(distances)
        if sigma is None:
            sys.exit("no validation renders with material colours: cannot fit the colour likelihood")
        print(f"classifier {row.name} on {gt_path}")
        print(f"colour sigma {sigma:.2f} CIELAB from {len(distances)} validation regions "
              f"(median dE {np.median(distances):.1f})")
        networks = session.execute(sa.select(m.PartSubstance.classifier_id).distinct()).scalars().all()
        session.commit()
        temperatures = {n: substance_temperature(settings, n) for n in networks if n is not None}
        print(f"substance network part temperatures {temperatures}")
        newest = max(temperatures)
        net_row = session.get(m.Classifier, newest)
        network = load_model(checkpoint_from_bytes(store.read_bytes(net_row.checkpoint_blob)))
        val = validation_renders(clf, data, labs, sigma, (network, int(net_row.config.get("size") or 128)),
                                 temperatures[newest], {mat.id: mat.substance for mat in materials})
        _print("validation renders, exact material regions", val)
        for ep in exemplar_pairs(session, store, gt):
            labels, mats, true_subs, part_map = ep.labels, ep.materials, ep.substances, ep.part_map
            image, subs, parts = ep.image, ep.part_substances, ep.parts
            items = []
            for part in parts:
                mask = part_map == part.index
                winner = _majority(labels, mask)
                if winner is None or mask.sum() < 16 or part.id not in subs or not subs[part.id].observed:
                    continue
                ps = subs[part.id]
                items.append((mask, mats[winner - 1], substance_vector(ps.probs),
                              true_subs[winner - 1], ps.substance,
                              substance_vector(temper(ps.probs, temperatures.get(ps.classifier_id)))))
            if not items:
                continue
            mat_probs, head_probs = clf.predict(image, [i[0] for i in items])
            for k, (mask, truth, network, true_sub, network_sub, calibrated) in enumerate(items):
                hits["network argmax (substance only)"].append((float("nan"), float("nan"),
                                                                float(network_sub == true_sub)))
                lab = median_lab(image, mask)
                colour = {f: color_likelihood(lab, labs, sigma * f)[None] for f in (0.5, 1.0, 2.0)}
                uniform = np.full_like(mat_probs[k:k + 1], 1.0)
                variants = {"none": (None, None), "network": (network, None), "head": (head_probs[k], None),
                            "both": (network * head_probs[k], None),
                            "network + colour (run 4)": (network, colour[1.0]),
                            "calibrated network": (calibrated, None),
                            "calibrated network + colour (pipeline)": (calibrated, colour[1.0]),
                            "network + colour, sigma / 2": (network, colour[0.5]),
                            "network + colour, 2 sigma": (network, colour[2.0]),
                            "colour only": (None, colour[1.0] * uniform[:, 1:]),
                            "sqrt(material head) x network x colour": (network, colour[1.0])}
                # marginal-first: the substance with the most posterior mass, then its best material
                subs_of = np.array(clf.material_substances)
                # diagnostic: a part smaller than the classifier's smallest training region (0.5% of the
                # image) is outside what the head was trained on; rank it without the head there
                head = mat_probs[k:k + 1]
                small = bool(mask.sum() < 0.005 * mask.size)
                if small:
                    head = np.full_like(head, 1.0)
                scores = clf.scores(head, calibrated[None], colour[1.0])[0]
                order = substance_first_order(scores, subs_of)[:5]
                picked = [names[clf.materials[i]] for i in order]
                hit7 = (float(picked[0] == truth), float(truth in picked), float(subs_of[order[0]] == true_sub))
                hits["calibrated network + colour, substance first, no head below 0.5%"].append(hit7)
                # inference-8: below 0.5% the substance network's own decision is the substance
                order8 = substance_first_order(scores, subs_of, network_sub if small else None)[:5]
                picked8 = [names[clf.materials[i]] for i in order8]
                hit8 = (float(picked8[0] == truth), float(truth in picked8), float(subs_of[order8[0]] == true_sub))
                hits["inference-8 (below 0.5%: no head, the network's substance)"].append(hit8)
                size = "below 0.5%" if small else "0.5% and up"
                hits[f"  inference-7, parts {size}"].append(hit7)
                hits[f"  inference-8, parts {size}"].append(hit8)
                hits[f"  network argmax, parts {size}"].append(
                    (float("nan"), float("nan"), float(network_sub == true_sub)))
                for label, weights in (("network", network), ("calibrated network", calibrated)):
                    scores = clf.scores(mat_probs[k:k + 1], weights[None], colour[1.0])[0]
                    order = substance_first_order(scores, subs_of)[:5]
                    best_sub = subs_of[order[0]]
                    picked = [names[clf.materials[i]] for i in order]
                    hits[f"{label} + colour, substance by marginal"].append(
                        (float(picked[0] == truth), float(truth in picked), float(best_sub == true_sub)))
                for name, (weights, colours) in variants.items():
                    probs = uniform if name == "colour only" else mat_probs[k:k + 1]
                    if name.startswith("sqrt"):  # a tempered material head: the other evidence weighs more
                        probs = np.sqrt(probs)
                    ranked = clf.top_k(probs, None if weights is None else weights[None], k=5,
                                       weight_by_substance=weights is not None, color_weights=colours)[0]
                    picked = [names[r.material_id] for r in ranked]
                    hits[name].append((float(picked[:1] == [truth]), float(truth in picked),
                                       float(ranked[0].substance == true_sub)))
    result = _summary(hits)
    _print("exemplars, aligned parts (what `photoshape eval` scores)", result)
    out = Path(__file__).parent / "results" / "substance_weighting.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"groundtruth": str(gt_path), "classifier": row.name, "color_sigma": sigma,
                               "substance_temperatures": temperatures,
                               "validation_renders": val, "results": result}, indent=2))


if __name__ == "__main__":
    main()
