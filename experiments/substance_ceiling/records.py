"""Per-region evidence records, so substance and material rankings can be scored offline.

Writes, for a demo database (PHOTOSHAPE_DATA_ROOT), one record per scored region with every piece
of evidence inference has: the material head's probabilities, the classifier's own substance head,
the substance network's part probabilities (raw) and its decision, the part's median CIELAB colour,
the region's share of the image, and the truth (material index in the classifier's order, substance):

  - "validation": the validation training renders' exact material regions (>= 0.5% of the image),
    the network run on each render as the substances stage runs it on an exemplar;
  - "exemplars":  the aligned parts of every aligned pair with demo ground truth, exactly as
    `photoshape eval` scores them (majority ground-truth label under the aligned mask).

Any ranking can then be scored from the JSON without re-running a network:
`experiments.substance_ceiling.run` does that. Nothing here is fit or chosen.

    PHOTOSHAPE_DATA_ROOT=... python -m experiments.substance_ceiling.records [groundtruth.json] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import resize_labels
from photoshape_flow.classify.assignment import median_lab
from photoshape_flow.classify.evidence import min_region_fraction
from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.classify.substance_recognition import substance_map
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.demo import newest_groundtruth
from photoshape_flow.evaluation.groundtruth import GroundTruthFile, read_groundtruth_file
from photoshape_flow.imaging.io import load_label_map, load_rgb
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.recognition.bn_prior import PhotoCase, photo_cases
from photoshape_flow.recognition.training import training_data
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.scoring.truths import majority_label, merge_labels, truth_labels
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import SUBSTANCES

from ..common import load_evidence, results_dir

VALIDATION_RENDERS = 400  # exact validation renders read for their regions

# -- ground truth as `photoshape eval` reads it (the same rules as pipeline/evaluate.py) ----------------


def exemplar_truths(session: Session, gt: GroundTruthFile) -> dict[int, Any]:
    """exemplar id -> its ground-truth entry, matched exactly as `photoshape eval` matches them (entries
    with a mask only: the records are per aligned pixel)."""
    matched = match_groundtruth(session, gt)
    for problem in matched.problems:
        print(f"skipped {problem}", file=sys.stderr)
    return {eid: entry for eid, entry in matched.truths.items() if entry.mask is not None}


def aligned_part_map(store: BlobStore, alignment: m.Alignment, size: int) -> np.ndarray:
    """The alignment's CRF part map at `size` x `size` (the stored exemplar's frame)."""
    part_map = store.load_image(alignment.crf_blob)
    if part_map.ndim == 3:
        part_map = part_map[..., 0]
    return resize_labels(part_map, size).astype(np.int32)


@dataclass
class ExemplarPair:
    """One aligned pair with demo ground truth, loaded as `photoshape eval` scores it."""

    pair: m.Pair
    exemplar: m.Exemplar
    labels: np.ndarray  # ground-truth label per pixel of the stored exemplar (0: background)
    materials: list[str]  # material name of label i + 1
    substances: list[str]  # substance of label i + 1
    part_map: np.ndarray  # the aligned (CRF) part map at the exemplar's size
    image: np.ndarray  # the exemplar's RGB
    part_substances: dict[int, m.PartSubstance]  # part id -> its row for this pair
    parts: list[m.Part]


def exemplar_pairs(session: Session, store: BlobStore, gt: GroundTruthFile) -> Iterator[ExemplarPair]:
    """Every aligned (flow-crf), non-excluded pair whose exemplar has ground truth, in pair order."""
    truths = exemplar_truths(session, gt)
    rows = session.execute(
        sa.select(m.Pair, m.Alignment).join(m.Alignment, m.Alignment.pair_id == m.Pair.id)
        .where(m.Alignment.status == "ok", m.Alignment.method == "flow-crf",
               m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)
        .order_by(m.Pair.id)
    ).all()
    for pair, alignment in rows:
        exemplar = session.get(m.Exemplar, pair.exemplar_id)
        labels, materials, substances = truth_labels(truths[exemplar.id], exemplar)
        yield ExemplarPair(
            pair=pair, exemplar=exemplar, labels=labels, materials=materials, substances=substances,
            part_map=aligned_part_map(store, alignment, labels.shape[0]),
            image=store.load_image(exemplar.image_blob)[..., :3],
            part_substances={ps.part_id: ps for ps in session.execute(
                sa.select(m.PartSubstance).where(m.PartSubstance.pair_id == pair.id)).scalars()},
            parts=list(session.execute(sa.select(m.Part).where(m.Part.shape_id == pair.shape_id)).scalars()),
        )


def validation_regions(
    items: Any, materials: Any, min_fraction: float = 0.005
) -> Iterator[tuple[int, np.ndarray, np.ndarray, list[tuple[int, np.ndarray]]]]:
    """(render number, material-id map, RGB, [(material id, mask)]) of each validation render with regions.

    Regions are the exact material regions of at least `min_fraction` of the image (the classifier's
    training threshold) whose material is in `materials`.
    """
    for number, item in enumerate(items):
        ids, rgb = load_label_map(item.material_map), load_rgb(item.image)
        minimum = int(np.ceil(min_fraction * ids.size))
        regions = [(int(v), ids == v) for v, c in zip(*np.unique(ids, return_counts=True), strict=True)
                   if v != 0 and c >= minimum and int(v) in materials]
        if regions:
            yield number, ids, rgb, regions


def render_records(number: int, rgb: np.ndarray, labels: np.ndarray, regions: list[tuple[int, int, np.ndarray]],
                   clf: Any, ev: Any, index: dict[int, int]) -> list[dict]:
    """One record per region (its value in `labels`, true material id, mask) of one render, the substance
    network run on the render and pooled over `labels` as the substances stage does on an exemplar."""
    mat, sub = clf.predict(rgb, [mask for _, _, mask in regions])
    net = part_substances(labels, substance_map(ev.network, rgb, labels, ev.net_size), [v for v, _, _ in regions])
    return [{"render": number, "fraction": float(mask.mean()), "truth": index[mid],
             "true_substance": ev.material_substance[mid], "network": part.substance,
             "network_probs": [float(part.probs.get(s, 0.0)) for s in SUBSTANCES],
             "head": mat[k].round(6).tolist(), "head_substance": sub[k].round(6).tolist(), "lab": _lab(rgb, mask)}
            for k, ((_, mid, mask), part) in enumerate(zip(regions, net, strict=True))]


def photo_like_records(cases: list[PhotoCase], clf: Any, ev: Any, index: dict[int, int]) -> list[dict]:
    """Records of validation renders made photo-like (degraded like exemplars, part maps misaligned as fine
    alignment errs: `recognition.bn_prior.photo_cases`)."""
    out = []
    for number, case in enumerate(cases):
        keep = [(mask, mid) for mask, mid in zip(case.masks, case.truth, strict=True) if mid in index]
        labels = np.zeros(case.image.shape[:2], np.int32)
        for k, (mask, _) in enumerate(keep):
            labels[mask] = k + 1
        regions = [(k + 1, mid, mask) for k, (mask, mid) in enumerate(keep)]
        if regions:
            out += render_records(number, case.image, labels, regions, clf, ev, index)
    return out


def _lab(rgb: np.ndarray, mask: np.ndarray) -> list[float] | None:
    lab = median_lab(rgb, mask)
    return None if lab is None else np.asarray(lab, np.float64).round(3).tolist()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("groundtruth", nargs="?", type=Path)
    parser.add_argument("--out", type=Path, help="default: <data root>/experiments/substance_ceiling/records.json")
    parser.add_argument("--photo-like", type=int, default=0, metavar="N",
                        help="also N validation renders made photo-like (records under 'photo_like')")
    args = parser.parse_args()
    settings = get_settings()
    out = args.out or results_dir(settings, "substance_ceiling") / "records.json"
    gt_path = args.groundtruth or newest_groundtruth(settings.data_root)
    if gt_path is None:
        sys.exit(f"{settings.data_root}: no demo ground truth; run `photoshape demo` or pass groundtruth.json")
    gt = read_groundtruth_file(gt_path)
    store = BlobStore(settings.blob_root)
    row, clf = load_material_classifier(settings=settings)
    index = {mid: i for i, mid in enumerate(clf.materials)}
    min_fraction = min_region_fraction(row.config)
    validation: list[dict] = []
    exemplars: list[dict] = []
    with session_scope() as session:
        ev = load_evidence(session, store, settings, clf.materials)
        data = training_data(session, store)
        for number, ids, rgb, regions in validation_regions(data.val[:VALIDATION_RENDERS], index, min_fraction):
            validation += render_records(number, rgb, ids, [(mid, mid, mask) for mid, mask in regions], clf, ev, index)
        photo_like = (photo_like_records(photo_cases(session, store, settings, args.photo_like), clf, ev, index)
                      if args.photo_like else [])
        names = {mat.id: mat.name for mat in session.execute(sa.select(m.Material)).scalars()}
        by_name = {name: mid for mid, name in names.items()}
        for ep in exemplar_pairs(session, store, gt):
            min_pixels = max(16, int(0.0005 * ep.part_map.size))
            mat_labels, mat_names = merge_labels(ep.labels, ep.materials)  # scored as `photoshape eval` does
            sub_labels, sub_names = merge_labels(ep.labels, ep.substances)
            items = []
            for part in ep.parts:
                mask = ep.part_map == part.index
                winner = majority_label(mat_labels, mask)
                ps = ep.part_substances.get(part.id)
                if winner is None or mask.sum() < min_pixels or ps is None or not ps.observed or not ps.substance:
                    continue
                truth = by_name.get(mat_names[winner - 1])
                if truth not in index:
                    continue
                sub_winner = majority_label(sub_labels, mask)
                items.append((part, mask, ps, index[truth], sub_names[sub_winner - 1] if sub_winner else None))
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
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "groundtruth": str(gt_path), "classifier": row.id, "materials": clf.materials,
        "material_substances": clf.material_substances, "labs": ev.labs.round(4).tolist(),
        "color_sigma": ev.sigma, "temperature": ev.temperature, "substance_network": ev.network_id,
        "min_region_fraction": min_fraction, "validation": validation, "exemplars": exemplars,
        "photo_like": photo_like,
    }))
    print(f"{len(validation)} validation regions, {len(exemplars)} exemplar parts -> {out}")


if __name__ == "__main__":
    main()
