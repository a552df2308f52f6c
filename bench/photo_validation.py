"""Which evidence may decide a part's substance on photos? Validation renders imaged like photos.

The ranking's evidence (material head, calibrated substance network, colour likelihood) is chosen on
the validation renders, which share the training renders' imaging: linear light tone-mapped the same
way, the same exposure, no white balance error. A photo has an unknown exposure and white balance,
and the colour likelihood compares absolute CIELAB colours against the materials' renders, so its
evidence may not survive that shift while the head's and the network's (texture, shading) do. This
bench re-images validation renders (held-out shapes and envmaps, never exemplars) as a camera would:
each render's own row re-rendered at photo size on transparent and passed through the demo's photo
model (`demo.exemplars.degrade`: exposure, white balance, blur, sensor noise, JPEG), lit by its own
validation envmap. On the exact material regions (>= 0.5% of the image) it scores, for the stored
render and the photo-like one:

  - network argmax:          the substance network's substance for the region (no-classifier's pick),
  - pipeline:                head x calibrated network x colour, substance decided first by mass,
  - colour within substance: the same with colour renormalised within each substance,
  - substance without colour: the substance decided by the mass of head x calibrated network, then
                             the best material of it by head x calibrated network x colour.

Prints material top-1 / top-5 / substance accuracy per ranking and writes
bench/results/photo_validation.json.

    PHOTOSHAPE_DATA_ROOT=... python bench/photo_validation.py [--count 200]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from photoshape_flow.classify.assignment import median_lab, substance_vector
from photoshape_flow.classify.color_prior import (
    color_likelihood,
)
from photoshape_flow.classify.dataset import load_label_map, load_rgb
from photoshape_flow.classify.infer import substance_first_order
from photoshape_flow.classify.substance_calibration import temper
from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.classify.substance_train import predict_substances
from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.training import load_material_classifier
from photoshape_flow.pipeline.training_renders import _Inputs
from photoshape_flow.store import BlobStore

sys.path.insert(0, str(Path(__file__).parent))
from ranking_evidence import load_evidence, validation_specs
from render_quality_gap import photo, regions


def rankings(clf, probs: np.ndarray, calibrated: np.ndarray, colour: np.ndarray) -> dict[str, int]:
    """The top-1 material index of each ranking for one region; substance-first throughout."""
    subs = np.array(clf.material_substances)
    full = clf.scores(probs[None], calibrated[None], colour[None])[0]
    within = colour.copy()
    for name in set(subs.tolist()):
        within[subs == name] /= max(float(colour[subs == name].sum()), 1e-300)
    no_colour = clf.scores(probs[None], calibrated[None])[0]
    mass = {name: float(no_colour[subs == name].sum()) for name in dict.fromkeys(subs.tolist())}
    best = max(mass, key=lambda name: mass[name])
    order = np.argsort(-full, kind="stable")
    first = next(int(i) for i in order if subs[i] == best)
    return {
        "pipeline": [int(i) for i in substance_first_order(full, subs)[:5]],
        "colour within substance": [int(i) for i in substance_first_order(
            clf.scores(probs[None], calibrated[None], within[None])[0], subs)[:5]],
        "substance without colour": [first] + [int(i) for i in order if i != first][:4],
    }


def _scores(hits: list[tuple[float, float, int]]) -> dict[str, float | int | None]:
    """Regions, top-1, top-5 (None for a substance-only row, whose material columns are NaN), substance."""
    top1, top5, substance = (np.array(column, dtype=np.float64) for column in zip(*hits, strict=True))
    material = not np.isnan(top1).all()
    return {"regions": len(hits), "top1": float(top1.mean()) if material else None,
            "top5": float(top5.mean()) if material else None, "substance": float(substance.mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=200, help="validation renders to re-image")
    parser.add_argument("--photo-size", type=int, default=320)
    parser.add_argument("--photo-spp", type=int, default=48)
    args = parser.parse_args()
    from photoshape_flow.render import Renderer

    settings = get_settings()
    store = BlobStore(settings.blob_root)
    row, clf = load_material_classifier(settings=settings)
    index = {mid: i for i, mid in enumerate(clf.materials)}
    subs = np.array(clf.material_substances)
    renderer = Renderer(resolve=store.resolve)
    inputs = _Inputs(store=store)
    hits: dict[str, dict[str, list[tuple[float, float, int]]]] = {
        "stored": defaultdict(list), "photo": defaultdict(list)}
    with session_scope() as session:
        ev = load_evidence(session, store, settings, clf.materials)
        labs, sigma, temperature, newest = ev.labs, ev.sigma, ev.temperature, ev.network_id
        network, net_size, material_substance = ev.network, ev.net_size, ev.material_substance
        picked = validation_specs(session, args.count)
        for rendering, spec in picked:
            inputs.load(session, spec)
            stored_ids = load_label_map(store.path(rendering.blobs["material_ids"]))
            found = regions(stored_ids, set(index))
            if not found:
                continue
            rgb_photo, ids_photo = photo(renderer, inputs.mesh(spec.shape_id), spec, inputs.material_specs(spec),
                                         inputs.envmap_spec(spec.envmap.envmap_id), args.photo_size, args.photo_spp)
            versions = {"stored": (load_rgb(store.path(rendering.blobs["beauty"])), stored_ids),
                        "photo": (rgb_photo, ids_photo)}
            masks = {name: [(mid, ids == mid) for mid, _ in found] for name, (_, ids) in versions.items()}
            if not all(mask.sum() >= 16 for ms in masks.values() for _, mask in ms):
                continue  # paired: both versions score the same regions
            for name, (rgb, ids) in versions.items():
                probs, _ = clf.predict(rgb, [mask for _, mask in masks[name]])
                net = part_substances(ids, predict_substances(network, rgb, net_size), [mid for mid, _ in found])
                for k, ((mid, mask), part) in enumerate(zip(masks[name], net, strict=True)):
                    truth, true_sub = index[mid], material_substance[mid]
                    calibrated = substance_vector(temper(part.probs, temperature))
                    colour = color_likelihood(median_lab(rgb, mask), labs, sigma)
                    hits[name]["network argmax"].append((float("nan"), float("nan"), int(part.substance == true_sub)))
                    for ranking, order in rankings(clf, probs[k, :], calibrated, colour).items():
                        hits[name][ranking].append((int(order[0] == truth), int(truth in order),
                                                    int(subs[order[0]] == true_sub)))
    summary = {name: {r: _scores(v) for r, v in table.items()} for name, table in hits.items()}
    print(f"classifier {row.name}, substance network {newest} (T {temperature}), colour sigma {sigma:.2f}, "
          f"{len(picked)} validation renders")
    print("| version | ranking | regions | top-1 | top-5 | substance |\n|---|---|---:|---:|---:|---:|")
    for name, table in summary.items():
        for r, s in table.items():
            top = " | ".join("—" if s[k] is None else f"{s[k]:.3f}" for k in ("top1", "top5"))
            print(f"| {name} | {r} | {s['regions']} | {top} | {s['substance']:.3f} |")
    out = Path(__file__).parent / "results" / "photo_validation.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"classifier": row.name, "substance_network": newest, "color_sigma": sigma,
                               "renders": len(picked), "results": summary}, indent=2))


if __name__ == "__main__":
    main()
