"""What the experiments share: the ranking's evidence as inference fits it, and one region scorer.

`load_evidence` gives the colour likelihood (colours and sigma as the training stage fits them), the calibrated
substance network (its part-level temperature) and the material colours that inference uses, so the
experiments score exactly what the pipeline ranks with. `region_hits` and `interval` score a classifier
on labelled regions (validation renders made photo-like, or a world's photos through true masks) the
same way for every experiment that compares classifiers. `results_dir` is where an experiment writes
its output: under the data root it measured, next to the networks the figures belong to.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.color_prior import material_lab_matrix
from photoshape_flow.classify.substance_configs import read_side_of
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.networks.calibrations import material_lab
from photoshape_flow.networks.classifier_rows import newest_classifier
from photoshape_flow.networks.classifiers import load_substance_network
from photoshape_flow.recognition.calibration import fit_color_evidence
from photoshape_flow.recognition.substance_temperature import substance_temperature
from photoshape_flow.scoring.evaluate import pair_truths
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_OK, SUBSTANCE_LABELS

# the columns of `region_hits`' rows
HIT_COLUMNS = ("case", "material", "top1", "top5", "substance_top", "substance_head", "substance_mass")


def region_hits(model: Any, cases: Sequence[Any], enabled: Iterable[int]) -> np.ndarray:
    """One row per labelled region whose true material the classifier knows, in `HIT_COLUMNS` order.

    `model` is a `classify.infer.MaterialClassifier`; each case has `image`, `masks` and `truth` (material
    ids). Only the `enabled` materials compete. Substance hits: of the top material, of the substance head,
    and of the material head's probability mass summed per substance.
    """
    keep = set(enabled)
    columns = np.array([i + 1 for i, mid in enumerate(model.materials) if mid in keep])
    ids = np.asarray(model.materials)[columns - 1]
    subs_of = np.asarray(model.material_substances)[columns - 1]
    rows: list[tuple[float, ...]] = []
    for c, case in enumerate(cases):
        mats, subs = model.predict(case.image, list(case.masks))
        p = mats[:, columns]
        for k, true in enumerate(case.truth):
            where = np.nonzero(ids == true)[0]
            if not len(where):
                continue
            t = int(where[0])
            order = np.argsort(-p[k])
            head = SUBSTANCE_LABELS[1 + int(np.argmax(subs[k][1:]))]
            mass = {s: float(p[k][subs_of == s].sum()) for s in set(subs_of)}
            rows.append((c, true, float(order[0] == t), float(t in order[:5]), float(subs_of[order[0]] == subs_of[t]),
                         float(head == subs_of[t]), float(max(mass, key=mass.get) == subs_of[t])))
    return np.asarray(rows, float).reshape(-1, len(HIT_COLUMNS))


def interval(values: np.ndarray, groups: np.ndarray, rng: np.random.Generator, draws: int = 1000) -> list[float] | None:
    """[mean, 2.5%, 97.5%] of `values`, resampling whole groups (renders or photos) with replacement; None if empty."""
    unique = np.unique(groups)
    if not len(unique):
        return None
    boot = [np.concatenate([values[groups == g] for g in rng.choice(unique, len(unique))]).mean() for _ in range(draws)]
    return [round(float(values.mean()), 3), round(float(np.percentile(boot, 2.5)), 3),
            round(float(np.percentile(boot, 97.5)), 3)]


def results_dir(settings: Settings, experiment: str) -> Path:
    """<data root>/experiments/<experiment>: an experiment's output for the networks of that data root."""
    return Path(settings.data_root) / "experiments" / experiment


@dataclass
class Evidence:
    material_substance: dict[int, str]
    labs: np.ndarray  # (M, 3) CIELAB of the classifier's materials as the ranking sees them (NaN: no colour)
    sigma: float | None  # the colour likelihood's sigma, fit as the training stage fits it
    network_id: int  # the newest substance network behind the part substances
    temperature: float | None  # its part-level temperature
    network: Any  # the substance network itself (segmentation net, or the part recogniser's MaterialClassifier)
    net_size: int  # its input size


def newest_substance_network(session: Session, network: int | None = None) -> Any:
    """The newest trained (status ok) substance network's row, or `network`'s; exits naming the gap."""
    row = newest_classifier(session, "substance") if network is None else session.get(m.Classifier, network)
    if row is None or row.kind != "substance" or row.status != STATUS_OK:
        raise SystemExit("no trained substance network in this data root: run the substances stage first")
    return row


def load_evidence(session: Session, store: BlobStore, settings: Settings, materials_order: list[int]) -> Evidence:
    """The evidence inference would use, for a classifier whose materials are `materials_order`."""
    materials = session.execute(sa.select(m.Material)).scalars().all()
    previews = {mat.id: lab for mat in materials if (lab := material_lab(mat, store)) is not None}
    mat_labs, sigma = fit_color_evidence(session, store, settings, previews)
    networks = session.execute(sa.select(m.PartSubstance.classifier_id).distinct()).scalars().all()
    newest = max(n for n in networks if n is not None)
    net_row = session.get(m.Classifier, newest)
    return Evidence(
        material_substance={mat.id: mat.substance for mat in materials},
        labs=material_lab_matrix(materials_order, mat_labs), sigma=sigma, network_id=newest,
        temperature=substance_temperature(settings, newest),
        network=load_substance_network(net_row, store, "cpu"),
        net_size=read_side_of(net_row.config) or 128,
    )


Candidate = tuple[int, str | None, str | None, dict[str, Any]]  # rank, material name, substance, fit params
ScoredPart = tuple[str, tuple[str, str], list[Candidate]]  # method key, (true material, substance), its rows


def scored_rankings(url: str, groundtruth: Path, source: str) -> list[ScoredPart]:
    """(method key, (true material, true substance), the method's rows best first) per scored part."""
    store = BlobStore(get_settings().blob_root)
    out = []
    with session_scope(url) as session:
        truths = match_groundtruth(session, read_groundtruth_file(groundtruth), source).truths
        names = dict(session.execute(sa.select(m.Material.id, m.Material.name)).all())
        rows = session.execute(
            sa.select(m.Assignment, m.Part.index).join(m.Part, m.Part.id == m.Assignment.part_id)
            .join(m.Pair, m.Pair.id == m.Assignment.pair_id)
            .where(m.Pair.exemplar_id.in_(list(truths)), ~m.Pair.exclude)).all()
        ranked: dict[tuple[int, int, str], list[Candidate]] = defaultdict(list)
        for a, index in rows:
            ranked[(a.pair_id, index, a.method_key)].append(
                (a.rank, names.get(a.material_id), a.substance, (a.params or {}).get("fit") or {}))
        by_pair: dict[int, dict[int, tuple[str, str]]] = {}
        for (pair_id, index, key), candidates in ranked.items():
            if pair_id not in by_pair:
                pair = session.get(m.Pair, pair_id)
                alignment = session.execute(sa.select(m.Alignment).where(
                    m.Alignment.pair_id == pair_id, m.Alignment.method == "flow-crf",
                    m.Alignment.status == "ok")).scalar_one_or_none()
                by_pair[pair_id] = {} if alignment is None else pair_truths(
                    session, store, pair, session.get(m.Exemplar, pair.exemplar_id), alignment,
                    truths[pair.exemplar_id])
            truth = by_pair[pair_id].get(index)
            if truth is not None:
                out.append((key, truth, sorted(candidates, key=lambda c: c[0])))
    return out
