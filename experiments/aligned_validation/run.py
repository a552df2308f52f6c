"""How should a part's substance be decided when its mask comes from the alignment? Validation renders
aligned like exemplars.

The ranking's evidence is chosen on validation renders with *exact* masks, but on exemplars every
mask comes from the pipeline's alignment (coarse pose from HOG retrieval, flow warp, dense CRF),
whose errors hit small parts hardest: a thin leg's aligned mask may cover its neighbour, and both the
colour likelihood and the substance network then read the neighbour's pixels. On the seed-0 medium
demo ours trailed the substance network's argmax on aligned parts smaller than the classifier's
smallest training region (docs/decisions.md, inference-8); this experiment builds the same situation without touching
the exemplars. Each validation render (held-out shapes and envmaps) is re-rendered at photo size,
imaged like a demo photo (`demo.exemplars.degrade`, JPEG), square-cropped like a stored exemplar, and
aligned by the pipeline's code to each of the profile's `exemplar_topk` nearest shapes of the whole
collection (each shape's best view of its stored HOG sweep: the coarse step's reverse index, so most
pairs are other shapes than the rendered one, as on the exemplars), the coarse part map at that
view (`align.partmap.render_coarse_part_map`), then `align.fine.align_pair` at the profile's working
size. Every aligned part is then scored as inference scores it (the same thresholds, the substance
network over the aligned map at the working size, the classifier and the colour of the aligned
mask at the image size), against the majority material under the aligned mask (as `photoshape
eval` does).

Rankings, split by the aligned part's share of the image (< / >= the classifier's
`min_region_fraction`):
  - network argmax: the substance network's decision for the part, `PartSubstance.substance`, a
                    per-pixel vote (the no-classifier baseline's pick),
  - inference-7:    head x calibrated network x colour, substance first; no head below the classifier's
                    smallest region (the pipeline's ranking before inference-8),
  - network decides small parts: inference-7, but below that size the network's substance is taken
                    (inference-8, the pipeline's ranking, adopted on this experiment's evidence),
  - no colour for small parts: below that size the calibrated network alone (the colour likelihood
                    dropped: the argmax of the part's mean probabilities, not the network's
                    per-pixel vote that `PartSubstance.substance` records),
and inference-7 with the colour sigma and substance temperature re-fit on the aligned regions of
the even-numbered renders, scored on the odd ones; and, for the small parts, the paired counts of
parts only one of two rankings gets right.

Writes <data root>/experiments/aligned_validation/aligned_validation.json (per-part records too, so
other rankings can be scored without re-rendering: `experiments.substance_ceiling.run --aligned`).

    PHOTOSHAPE_DATA_ROOT=... python -m experiments.aligned_validation.run [--count 300] [--profile medium]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.assignment import median_lab, substance_vector
from photoshape_flow.classify.color_prior import fit_color_sigma
from photoshape_flow.classify.evidence import ClassifierEvidence
from photoshape_flow.classify.ranking import scores as ranking_scores
from photoshape_flow.classify.ranking import substance_first_order
from photoshape_flow.classify.substance_calibration import fit_temperature, temper
from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.classify.substance_train import predict_substances
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.recognition.training_renders import RenderInputs
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec
from photoshape_flow.vocab import SUBSTANCES

from ..common import load_evidence, results_dir


def validation_specs(session: Session, count: int) -> list[tuple[m.Rendering, RenderSpec]]:
    """About `count` validation training renders spread evenly over their keys, with their specs."""
    rows = session.execute(
        sa.select(m.Rendering).where(m.Rendering.kind == "training", m.Rendering.split == "val",
                                     m.Rendering.status == "ok").order_by(m.Rendering.key)
    ).scalars().all()
    step = max(1, len(rows) // max(1, count))
    out = []
    for rendering in rows[::step][:count]:
        params = dict(rendering.params)
        for key in ("size", "spp"):  # rendering settings, not part of the spec
            params.pop(key)
        out.append((rendering, RenderSpec.from_dict(params)))
    return out


def photo_with_parts(renderer, mesh, spec: RenderSpec, material_specs, envmap_spec, size: int, spp: int):
    """(sRGB uint8, part-ID map, foreground) of `spec` imaged like a demo exemplar: rendered on
    transparent at photo size, then the demo's photo degradation (exposure, white balance, blur,
    noise) and JPEG."""
    import cv2

    from photoshape_flow.demo.exemplars import degrade, encode_jpeg, sample_degradation
    from photoshape_flow.synth.example import build_scene_inputs

    camera, materials, uv_transforms, envmap = build_scene_inputs(mesh, spec, material_specs, envmap_spec)
    result = renderer.beauty(mesh, materials, camera, envmap, size=size, spp=spp, uv_transforms=uv_transforms,
                             background="transparent", seed=int(spec.seed % (2**31 - 1)))
    params = sample_degradation(np.random.default_rng(spec.seed % 2**32))
    jpeg = encode_jpeg(degrade(result.hdr, result.alpha, params), params["jpeg_quality"])
    rgb = cv2.cvtColor(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    part_ids = np.asarray(renderer.part_ids(mesh, camera, size=size))
    return rgb, part_ids, np.asarray(result.alpha) >= 0.5


def resize_probs(probs: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """(S, H, W) per-pixel substance probabilities resized to `shape`, renormalised (as the substances stage)."""
    import cv2

    h, w = int(shape[0]), int(shape[1])
    out = np.stack([cv2.resize(c, (w, h), interpolation=cv2.INTER_LINEAR) for c in probs.astype(np.float32)])
    return out / np.maximum(out.sum(axis=0, keepdims=True), 1e-8)


def as_exemplar(rgb: np.ndarray, part_ids: np.ndarray, fg: np.ndarray):
    """The tight square crop of the foreground, as ingestion stores an exemplar (white outside)."""
    from photoshape_flow.imaging.squares import crop_square, square_box

    box = square_box(fg)
    if box is None:
        return None
    x0, y0, side = box
    return (crop_square(rgb, x0, y0, side, fill=255), crop_square(part_ids, x0, y0, side, fill=0),
            crop_square(fg, x0, y0, side, fill=False))


def _substance_of(r: dict, top1: int | None) -> str:
    return r["material_substances"][top1] if top1 is not None else r["network"]


def _paired(records: list[dict], rank_a, rank_b) -> tuple[int, int]:
    """Small parts whose substance only `rank_a` gets right, and those only `rank_b` gets right."""
    only_a = only_b = 0
    for r in records:
        if not r["small"]:
            continue
        a = _substance_of(r, rank_a(r)) == r["true_substance"]
        b = _substance_of(r, rank_b(r)) == r["true_substance"]
        only_a += int(a and not b)
        only_b += int(b and not a)
    return only_a, only_b


def _region_hits(records: list[dict], rank) -> dict[str, dict[str, float]]:
    """Substance accuracy (and material top-1) of one ranking, by part size."""
    out: dict[str, list[tuple[int, int]]] = defaultdict(list)
    for r in records:
        top1 = rank(r)
        hit = (int(top1 == r["truth"]) if top1 is not None else -1, int(_substance_of(r, top1) == r["true_substance"]))
        out["small" if r["small"] else "large"].append(hit)
        out["own shape" if r["own_shape"] else "other shapes"].append(hit)
        out["all"].append(hit)
    return {size: {"parts": len(v), "substance": float(np.mean([h[1] for h in v])),
                   "top1": None if v[0][0] < 0 else float(np.mean([h[0] for h in v]))}
            for size, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=300, help="validation renders to align")
    parser.add_argument("--profile", default="medium", help="pipeline profile (its fine-alignment size)")
    parser.add_argument("--photo-size", type=int, default=320)
    parser.add_argument("--photo-spp", type=int, default=48)
    args = parser.parse_args()
    import cv2

    from photoshape_flow.align.descriptors import HogParams, exemplar_descriptor
    from photoshape_flow.align.fine import FineParams, align_pair, part_label_accuracy
    from photoshape_flow.align.partmap import render_coarse_part_map, resize_labels
    from photoshape_flow.align.viewpoints import cameras_from_rows
    from photoshape_flow.imaging.squares import square_box
    from photoshape_flow.profiles import PROFILES
    from photoshape_flow.render.renderer import Renderer

    settings = get_settings()
    store = BlobStore(settings.blob_root)
    fine = FineParams(size=PROFILES[args.profile].fine_alignment.size)
    row, clf = load_material_classifier(settings=settings)
    policy = ClassifierEvidence.for_classifier(clf, row.config).policy
    min_fraction = policy.min_region_fraction
    index = {mid: i for i, mid in enumerate(clf.materials)}
    renderer = Renderer(resolve=store.resolve)
    inputs = RenderInputs(store=store)
    records: list[dict] = []
    accuracies: list[float] = []
    start = time.perf_counter()
    with session_scope() as session:
        ev = load_evidence(session, store, settings, clf.materials)
        material_substance, labs, sigma, temperature = ev.material_substance, ev.labs, ev.sigma, ev.temperature
        network, net_size, newest = ev.network, ev.net_size, ev.network_id
        if not hasattr(network, "width"):  # the per-pixel map below needs the segmentation network
            sys.exit("aligned_validation reads the from-scratch segmentation network's per-pixel map; this "
                     "collection's substance network is the part recogniser (D53)")
        cameras, hog, shape_of_row, blocks = None, None, [], []
        for feature in session.execute(sa.select(m.ViewFeature).where(m.ViewFeature.status == "ok")
                                       .order_by(m.ViewFeature.shape_id)).scalars():
            if cameras is None:
                cameras = cameras_from_rows(session.get(m.ViewpointSet, feature.viewpoint_set_id).cameras)
                hog = HogParams.from_dict(feature.meta["hog"])
            blocks.append(store.load_array(feature.feature_blob).astype(np.float32))
            shape_of_row += [feature.shape_id] * len(blocks[-1])
        feats, shape_of_row = np.concatenate(blocks), np.asarray(shape_of_row)
        feat_norms = (feats**2).sum(axis=1)
        first_row = {int(sid): int(i) for i, sid in reversed(list(enumerate(shape_of_row)))}  # a shape's view 0
        topk = PROFILES[args.profile].coarse_alignment.exemplar_topk
        picked = validation_specs(session, args.count)
        for number, (_, spec) in enumerate(picked):
            inputs.load(session, spec)
            rgb, part_ids, fg = photo_with_parts(
                renderer, inputs.mesh(spec.shape_id), spec, inputs.material_specs(spec),
                inputs.envmap_spec(spec.envmap.envmap_id), args.photo_size, args.photo_spp)
            part_ids = part_ids.astype(np.int32)
            crop = as_exemplar(rgb, part_ids, fg)
            if crop is None:
                continue
            rgb, part_ids, fg = crop
            # the coarse step: the exemplar's nearest shapes by their best view (the reverse index's top-k)
            query = exemplar_descriptor(rgb, fg.astype(np.uint8) * 255, hog).astype(np.float32)
            distances = feat_norms - 2.0 * feats @ query + float(query @ query)
            best_view: dict[int, int] = {}
            for row_index in np.argsort(distances, kind="stable"):
                best_view.setdefault(int(shape_of_row[row_index]), int(row_index))
                if len(best_view) == topk:
                    break
            fg_small = cv2.resize(fg.astype(np.float32), (fine.size, fine.size), interpolation=cv2.INTER_AREA) >= 0.5
            net_probs = resize_probs(predict_substances(network, rgb, net_size), (fine.size, fine.size))
            material_lut = np.zeros(part_ids.max(initial=0) + 1, np.int64)
            for p in spec.parts:
                if p.index < len(material_lut):
                    material_lut[p.index] = p.material_id
            truth_map = material_lut[part_ids]
            for shape_id, row_index in best_view.items():
                if shape_id not in inputs.shapes:
                    inputs.shapes[shape_id] = session.get(m.Shape, shape_id)
                camera = cameras[row_index - first_row[shape_id]]
                try:
                    coarse = render_coarse_part_map(renderer, inputs.mesh(shape_id), camera, fine.size,
                                                    target_box=square_box(fg_small))
                except ValueError:
                    continue
                aligned = align_pair(coarse, rgb, fg, fine).crf.astype(np.int32)
                own = shape_id == spec.shape_id
                if own:
                    accuracies.append(part_label_accuracy(aligned, resize_labels(part_ids, fine.size)))
                part_map = resize_labels(aligned, rgb.shape[0])  # inference's mask frame: the exemplar's size
                min_pixels = max(16, int(0.0005 * part_map.size))
                indices = [int(i) for i in np.unique(aligned) if i > 0 and int((part_map == i).sum()) >= min_pixels]
                if not indices:
                    continue
                net_parts = part_substances(aligned, net_probs, indices)  # substances stage: working size
                masks = [part_map == i for i in indices]
                head, head_substance = clf.predict(rgb, masks)
                for k, (mask, net) in enumerate(zip(masks, net_parts, strict=True)):
                    values = truth_map[mask]
                    if not net.observed or (values > 0).sum() < 0.5 * values.size:
                        continue
                    truth = int(np.bincount(values[values > 0]).argmax())
                    if truth not in index:
                        continue
                    lab = median_lab(rgb, mask)
                    records.append({
                        "render": number, "own_shape": bool(own), "fraction": float(mask.sum() / mask.size),
                        "small": bool(mask.sum() < min_fraction * mask.size),
                        "truth": index[truth], "true_substance": material_substance[truth],
                        "network": net.substance, "network_probs": [net.probs[s] for s in SUBSTANCES],
                        "head": head[k].tolist(), "head_substance": head_substance[k].tolist(),
                        "lab": None if lab is None else np.asarray(lab).tolist(),
                    })
            if number % 25 == 0:
                print(f"{number + 1}/{len(picked)} renders, {len(records)} parts, "
                      f"{time.perf_counter() - start:.0f} s", flush=True)
    subs = list(clf.material_substances)
    for r in records:
        r["material_substances"] = subs

    def scores(r: dict, use_head: bool, use_colour: bool, t: float | None, s: float) -> np.ndarray:
        evidence = ClassifierEvidence(policy, (labs, s) if use_colour else None)
        return ranking_scores(policy, evidence.of_lab(
            np.asarray(r["head"]) if use_head else None,
            substance_vector(temper(dict(zip(SUBSTANCES, r["network_probs"], strict=True)), t)), r["lab"]))

    def ranking(small_rule: str, t: float | None = temperature, s: float = sigma):
        def rank(r: dict) -> int | None:
            if not r["small"]:
                return int(substance_first_order(scores(r, True, True, t, s), subs)[0])
            if small_rule == "inference-7":
                return int(substance_first_order(scores(r, False, True, t, s), subs)[0])
            if small_rule == "network decides":
                return int(substance_first_order(scores(r, False, True, t, s), subs, substance=r["network"])[0])
            if small_rule == "no colour":
                return int(substance_first_order(scores(r, False, False, t, s), subs)[0])
            raise ValueError(small_rule)
        return rank

    results = {"network argmax": _region_hits(records, lambda r: None)}
    for rule in ("inference-7", "network decides", "no colour"):
        results[rule] = _region_hits(records, ranking(rule))
    paired = {rule: _paired(records, ranking(rule), ranking("inference-7"))
              for rule in ("network decides", "no colour")}
    paired["network argmax"] = _paired(records, lambda r: None, ranking("inference-7"))
    # colour sigma and temperature as they would be fit on aligned regions: even renders fit, odd ones score
    fit_part = [r for r in records if r["render"] % 2 == 0]
    test_part = [r for r in records if r["render"] % 2 == 1]
    distances = [float(np.linalg.norm(np.asarray(r["lab"]) - labs[r["truth"]])) for r in fit_part
                 if r["lab"] is not None and not np.isnan(labs[r["truth"]]).any()]
    sigma_aligned = fit_color_sigma(distances) or sigma
    t_aligned = fit_temperature(np.asarray([r["network_probs"] for r in fit_part]),
                                [SUBSTANCES.index(r["true_substance"]) for r in fit_part]) or temperature
    held_out = {"network argmax": _region_hits(test_part, lambda r: None),
                "inference-7": _region_hits(test_part, ranking("inference-7")),
                "inference-7, sigma and T fit on aligned regions":
                    _region_hits(test_part, ranking("inference-7", t_aligned, sigma_aligned))}
    summary = {
        "classifier": row.name, "substance_network": newest, "temperature": temperature, "color_sigma": sigma,
        "aligned_fit": {"temperature": t_aligned, "color_sigma": sigma_aligned, "renders": "even"},
        "renders": len(picked), "fine_size": fine.size, "min_region_fraction": min_fraction,
        "alignment_accuracy": float(np.mean(accuracies)) if accuracies else None,
        "seconds": round(time.perf_counter() - start, 1), "results": results, "held_out_odd": held_out,
        "small_parts_vs_inference_7": {k: {"only_this": a, "only_inference_7": b} for k, (a, b) in paired.items()},
    }
    def num(value: float | None, digits: int = 3) -> str:
        return "none" if value is None else f"{value:.{digits}f}"

    print(f"classifier {row.name}, network {newest} (T {num(temperature)}), colour sigma {num(sigma, 2)}; "
          f"{len(picked)} renders, {len(records)} aligned parts, part-label accuracy after the CRF "
          f"{num(summary['alignment_accuracy'])}")
    for title, table in (("all renders", results),
                         (f"odd renders (aligned fit on even: T {num(t_aligned)}, sigma {num(sigma_aligned, 2)})",
                          held_out)):
        print(f"\n{title}\n| ranking | substance, small (n) | substance, large (n) | own shape | other shapes "
              "| all | top-1 all |\n|---|---:|---:|---:|---:|---:|---:|")
        for name, r in table.items():
            small, large, every = r.get("small", {}), r.get("large", {}), r["all"]
            top1 = "—" if every["top1"] is None else f"{every['top1']:.3f}"
            print(f"| {name} | {small.get('substance', float('nan')):.3f} ({small.get('parts', 0)}) "
                  f"| {large.get('substance', float('nan')):.3f} ({large.get('parts', 0)}) "
                  f"| {r.get('own shape', {}).get('substance', float('nan')):.3f} "
                  f"| {r.get('other shapes', {}).get('substance', float('nan')):.3f} "
                  f"| {every['substance']:.3f} | {top1} |")
    print("\nsmall parts, substance right only here / only with inference-7:")
    for rule, (a, b) in paired.items():
        print(f"  {rule}: {a} / {b}")
    out = results_dir(settings, "aligned_validation") / "aligned_validation.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({**summary, "records": [{k: v for k, v in r.items() if k != "material_substances"}
                                                       for r in records]}))
    print(f"wrote {out}", file=sys.stderr)


if __name__ == "__main__":
    main()
