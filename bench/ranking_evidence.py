"""What the validation benches load once: the ranking's evidence as inference fits it, and the renders.

Shared by `photo_validation.py` and `aligned_validation.py` (imported from the bench folder), so
both score exactly the colour likelihood (sigma fit on the validation renders), the calibrated
substance network (its part-level temperature) and the material colours that inference uses.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.color_prior import fit_color_sigma, material_lab_matrix, region_color_distances
from photoshape_flow.classify.dataset import load_label_map, load_rgb
from photoshape_flow.classify.substance_train import checkpoint_from_bytes, load_model
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.pipeline.evaluate import _exemplar_truths, _part_map, truth_labels
from photoshape_flow.pipeline.inference import COLOR_SIGMA_RENDERS, material_lab
from photoshape_flow.pipeline.substances import substance_temperature
from photoshape_flow.pipeline.training import training_data
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.spec import RenderSpec


@dataclass
class Evidence:
    material_substance: dict[int, str]
    labs: np.ndarray  # (M, 3) CIELAB of the classifier's materials, in its order (NaN: no colour)
    sigma: float | None  # the colour likelihood's sigma, fit on the validation renders
    network_id: int  # the newest substance network behind the part substances
    temperature: float | None  # its part-level temperature
    network: Any  # the substance network itself
    net_size: int  # its input size


def load_evidence(session: Session, store: BlobStore, settings: Settings, materials_order: list[int]) -> Evidence:
    """The evidence inference would use, for a classifier whose materials are `materials_order`."""
    materials = session.execute(sa.select(m.Material)).scalars().all()
    mat_labs = {mat.id: lab for mat in materials if (lab := material_lab(mat, store)) is not None}
    data = training_data(session, store)
    sigma = fit_color_sigma(region_color_distances(data.val, mat_labs, limit=COLOR_SIGMA_RENDERS))
    networks = session.execute(sa.select(m.PartSubstance.classifier_id).distinct()).scalars().all()
    newest = max(n for n in networks if n is not None)
    net_row = session.get(m.Classifier, newest)
    return Evidence(
        material_substance={mat.id: mat.substance for mat in materials},
        labs=material_lab_matrix(materials_order, mat_labs), sigma=sigma, network_id=newest,
        temperature=substance_temperature(settings, newest),
        network=load_model(checkpoint_from_bytes(store.read_bytes(net_row.checkpoint_blob))),
        net_size=int(net_row.config.get("size") or 128),
    )


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


@dataclass
class ExemplarPair:
    """One aligned pair with demo ground truth, loaded as the accuracy benches score it."""

    pair: m.Pair
    exemplar: m.Exemplar
    labels: np.ndarray  # ground-truth label per pixel of the stored exemplar (0: background)
    materials: list[str]  # material name of label i + 1
    substances: list[str]  # substance of label i + 1
    part_map: np.ndarray  # the aligned (CRF) part map at the exemplar's size
    image: np.ndarray  # the exemplar's RGB
    part_substances: dict[int, m.PartSubstance]  # part id -> its row for this pair
    parts: list[m.Part]


def exemplar_pairs(session: Session, store: BlobStore, gt: Any) -> Iterator[ExemplarPair]:
    """Every aligned (flow-crf), non-excluded pair whose exemplar has ground truth, in pair order."""
    truths = _exemplar_truths(session, gt, None)
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
            part_map=_part_map(store, alignment, labels.shape[0]),
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
    training threshold) whose material is in `materials`, as the validation benches score them.
    """
    for number, item in enumerate(items):
        ids, rgb = load_label_map(item.material_map), load_rgb(item.image)
        minimum = int(np.ceil(min_fraction * ids.size))
        regions = [(int(v), ids == v) for v, c in zip(*np.unique(ids, return_counts=True), strict=True)
                   if v != 0 and c >= minimum and int(v) in materials]
        if regions:
            yield number, ids, rgb, regions
