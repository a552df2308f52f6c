"""Does the substance network read a small part better from a zoomed crop around it than from the whole photo?

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.small_parts.run \\
        --groundtruth ../second-world/groundtruth.json --source second-world

The substances stage reads each exemplar whole at the network's input size (`substances.size`) and
votes per part over its aligned map (`classify.substance_parts`); a leg under 1.5% of the frame is
then a few pixels wide. Here each part under `--small` of its map is also read from a square crop
around it, sized so the part's box spans `--fill` of the crop's side, resized to the network's
input; the vote is the same rule over the crop's part map. Two sets, each part's substance against
its truth: the data root's validation renders seen as exemplars (`networks.validation_photos`:
degraded at the exemplars' size, framed, the part map misaligned: where a choice may be made) and,
with `--groundtruth`, the evaluation world's exemplars through their CRF maps (attribution only).
Read-only; output `<data root>/experiments/small_parts/results.json`.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa

from experiments.common import Evidence, load_evidence, results_dir
from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.classify.color_prior import color_likelihood
from photoshape_flow.classify.ranking import substance_first_order
from photoshape_flow.classify.substance_calibration import temper
from photoshape_flow.classify.substance_parts import PartSubstanceResult, part_substances
from photoshape_flow.classify.substance_recognition import substance_map
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.bootstrap import difference_interval
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.hashing import item_seed
from photoshape_flow.networks.validation_photos import calibration_photo, exemplar_size, validation_renders
from photoshape_flow.recognition.inference import ALIGNMENT_METHOD
from photoshape_flow.recognition.substances import resize_probs
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.scoring.truths import pair_truths
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec

Photo = tuple[str, np.ndarray, np.ndarray, dict[int, str]]  # group, RGB uint8, part map, part -> true substance


def read(network: Any, size: int, rgb: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """The network's substance probabilities of `rgb` at the part map's size (any sizes), as the stage reads."""
    probs = substance_map(network, rgb, labels, size)
    return resize_probs(probs, labels.shape) if probs.shape[1:] != labels.shape else probs


def vote(labels: np.ndarray, probs: np.ndarray, index: int) -> PartSubstanceResult:
    """The stage's vote for part `index` (`classify.substance_parts`)."""
    return part_substances(labels, probs, [index])[0]


def labels_at(labels: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The part map at an image's size (nearest pixel), for the part's colour in that image."""
    ys = np.clip((np.arange(shape[0]) * labels.shape[0] / shape[0]).astype(int), 0, labels.shape[0] - 1)
    xs = np.clip((np.arange(shape[1]) * labels.shape[1] / shape[1]).astype(int), 0, labels.shape[1] - 1)
    return labels[np.ix_(ys, xs)]


def colour_picks(evidence: Evidence, order: list[int], rgb: np.ndarray, image_labels: np.ndarray, index: int,
                 network_vote: PartSubstanceResult) -> dict[str, str]:
    """The substance of the first pick under D20's rule's alternatives for a small part: colour x the
    network's calibrated confidence (inference-7, the substance with the most mass first) and the
    part's colour alone (the material of the nearest colour)."""
    colour = color_likelihood(median_lab(rgb, image_labels == index), evidence.labs, evidence.sigma or 1.0)
    subs = [evidence.material_substance[i] for i in order]
    confidence = temper(network_vote.probs, evidence.temperature)
    product = colour * np.array([confidence.get(sub, 0.0) for sub in subs])
    return {"confidence x colour": subs[int(substance_first_order(product, subs)[0])],
            "colour": subs[int(np.argmax(colour))]}


def zoomed(rgb: np.ndarray, labels: np.ndarray, index: int, fill: float) -> tuple[np.ndarray, np.ndarray]:
    """The square around part `index` (its box spanning `fill` of the side), in the image's pixels, padded
    with white outside the photo; and the part map over the same square."""
    ys, xs = np.nonzero(labels == index)
    sy, sx = rgb.shape[0] / labels.shape[0], rgb.shape[1] / labels.shape[1]
    cy, cx = (ys.min() + ys.max() + 1) / 2 * sy, (xs.min() + xs.max() + 1) / 2 * sx
    side = max((ys.max() - ys.min() + 1) * sy, (xs.max() - xs.min() + 1) * sx) / fill
    half = max(int(np.ceil(side / 2)), 8)
    y0, x0 = int(round(cy)) - half, int(round(cx)) - half
    pad = 2 * half
    canvas = np.full((pad, pad, 3), 255, np.uint8)
    out_labels = np.zeros((pad, pad), labels.dtype)
    yy, xx = np.mgrid[y0:y0 + pad, x0:x0 + pad]
    inside = (yy >= 0) & (yy < rgb.shape[0]) & (xx >= 0) & (xx < rgb.shape[1])
    canvas[inside] = rgb[yy[inside], xx[inside]]
    ly = np.clip((yy / sy).astype(int), 0, labels.shape[0] - 1)
    lx = np.clip((xx / sx).astype(int), 0, labels.shape[1] - 1)
    out_labels[inside] = labels[ly[inside], lx[inside]]
    return canvas, out_labels


def validation_photos(session: Any, store: BlobStore, seed: int, count: int) -> Iterator[Photo]:
    substance = dict(session.execute(sa.select(m.Material.id, m.Material.substance)).all())
    side = exemplar_size(session) or 320
    for row in validation_renders(session, count, seed):
        truth = RenderSpec.from_dict(row.params).material_by_index()
        hdr, ids = store.load_image(row.blobs["hdr"]), store.load_image(row.blobs["part_ids"])
        ids = ids[..., 0] if ids.ndim == 3 else ids
        rng = np.random.default_rng(item_seed(seed, "small-parts", row.kind, row.key))
        rgb, labels, _ = calibration_photo(hdr, ids, side, side, rng)
        yield (f"{row.kind}/{row.key}", rgb, labels.astype(np.int64),
               {i: substance[mid] for i, mid in truth.items() if mid in substance})


def world_photos(session: Any, store: BlobStore, groundtruth: Path, source: str | None) -> Iterator[Photo]:
    truths = match_groundtruth(session, read_groundtruth_file(groundtruth), source).truths
    for pair, alignment in session.execute(sa.select(m.Pair, m.Alignment).join(m.Alignment, sa.and_(
            m.Alignment.pair_id == m.Pair.id, m.Alignment.method == ALIGNMENT_METHOD, m.Alignment.status == "ok"))
            .where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude).order_by(m.Pair.id)).all():
        exemplar = session.get(m.Exemplar, pair.exemplar_id)
        scored = pair_truths(session, store, pair, exemplar, alignment, truths[pair.exemplar_id])
        if not scored or not alignment.crf_blob or not exemplar.image_blob:
            continue
        labels = store.load_image(alignment.crf_blob)
        rgb = store.load_image(exemplar.image_blob)
        rgb = np.repeat(rgb[..., None], 3, axis=2) if rgb.ndim == 2 else rgb[..., :3]
        yield (f"exemplar/{exemplar.id}", rgb, (labels[..., 0] if labels.ndim == 3 else labels).astype(np.int64),
               {i: sub for i, (_, sub) in scored.items()})


def measure(photos: Iterator[Photo], evidence: Evidence, order: list[int], small: float,
            fill: float) -> dict[str, Any]:
    """Substance accuracy on the small parts of the network's whole-photo vote (the stage's, D20), its
    zoomed vote, and D20's alternatives; each against the vote, paired by photo."""
    hits: dict[str, dict[str, list[float]]] = {}
    large_by: dict[str, list[float]] = {}
    network, size = evidence.network, evidence.net_size
    for group, rgb, labels, truth in photos:
        probs = read(network, size, rgb, labels)  # once per photo, as the stage reads it
        image_labels = labels_at(labels, rgb.shape)
        for index, substance in truth.items():
            share = float((labels == index).mean())
            if share == 0.0:
                continue
            whole = vote(labels, probs, index)
            if share >= small:
                large_by.setdefault(group, []).append(float(whole.substance == substance))
                continue
            crop, crop_labels = zoomed(rgb, labels, index, fill)
            picks = {"network (whole photo)": whole.substance,
                     "network (zoomed)": vote(crop_labels, read(network, size, crop, crop_labels), index).substance,
                     **colour_picks(evidence, order, rgb, image_labels, index, whole)}
            for rule, pick in picks.items():
                hits.setdefault(rule, {}).setdefault(group, []).append(float(pick == substance))
    base = hits.get("network (whole photo)", {})
    large = [v for vs in large_by.values() for v in vs]
    out: dict[str, Any] = {"small_parts": sum(len(v) for v in base.values()), "large_parts": len(large),
                           "large_whole": float(np.mean(large)) if large else None, "rules": {},
                           "by_photo": {"small": hits, "large": large_by}}  # for compare.py
    for rule, by in hits.items():
        diff = difference_interval(by, base)
        out["rules"][rule] = {"substance": float(np.mean([v for vs in by.values() for v in vs])),
                              "vs_network": {"value": diff.value, "low": diff.low, "high": diff.high}}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--groundtruth", type=Path, default=None, help="an evaluation world (attribution only)")
    parser.add_argument("--source", default=None)
    parser.add_argument("--small", type=float, default=0.015, help="a part under this share of its map is small")
    parser.add_argument("--fill", type=float, default=0.35, help="the part's box spans this much of the crop")
    parser.add_argument("--count", type=int, default=400, help="validation renders at most")
    args = parser.parse_args()
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    results: dict[str, Any] = {"small": args.small, "fill": args.fill}
    with session_scope(settings.resolved_database_url) as session:  # read-only
        order = sorted(session.execute(sa.select(m.Material.id).where(m.Material.enabled)).scalars())
        evidence = load_evidence(session, store, settings, order)
        sets = {"validation renders": validation_photos(session, store, settings.seed, args.count)}
        if args.groundtruth is not None:
            sets["world"] = world_photos(session, store, args.groundtruth, args.source)
        for name, photos in sets.items():
            results[name] = measure(photos, evidence, order, args.small, args.fill)
            print(f"{name}: {results[name]['small_parts']} small parts; larger parts, network "
                  f"{results[name]['large_whole']:.3f} ({results[name]['large_parts']})")
            for rule, cell in results[name]["rules"].items():
                d = cell["vs_network"]
                print(f"  {rule:24s} {cell['substance']:.3f}  vs network {d['value']:+.3f} ({d['low']:+.3f}, "
                      f"{d['high']:+.3f})", flush=True)
        session.rollback()
    out = results_dir(settings, "small_parts")
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
