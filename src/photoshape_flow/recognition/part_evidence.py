"""What the inference stage knows of each part of a pair, and how one method ranks materials for it.

`RankingContext` holds what a run needs once (enabled materials and their colours, the classifier
and its stored evidence and calibrations, `CODE_VERSION` of the ranking policy); `part_inputs` gives
each part its mask in the aligned part map and the substance it is ranked under (observed, the
substance network's, or a prior); `rank_part` ranks one part by the run's method. Writing the
ranked rows is `recognition.inference`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.assignment import (
    RankedMaterial,
    color_match,
    median_lab,
    random_of_substance,
    substance_vector,
)
from photoshape_flow.classify.evidence import ClassifierEvidence
from photoshape_flow.classify.infer import load_classifier
from photoshape_flow.classify.substance_calibration import temper
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.devices import set_torch_threads
from photoshape_flow.hashing import item_seed
from photoshape_flow.networks.calibrations import Calibration, material_lab, stored_temperature
from photoshape_flow.networks.classifiers import substance_networks
from photoshape_flow.networks.evidence import stored_evidence
from photoshape_flow.store import BlobStore
from photoshape_flow.synth.priors import empirical_prior, name_prior, restrict
from photoshape_flow.vocab import SUBSTANCES

log = logging.getLogger(__name__)

# the ranking policy's version: part of every row's params_hash (docs/decisions.md lists each version)
CODE_VERSION = "inference-9"


@dataclass
class PartInput:
    part: m.Part
    mask: np.ndarray | None  # None: unobserved
    substance: PartSubstanceView
    color: dict[int, float] | None = None  # material id -> colour likelihood, when the ranking used it
    head: bool = True  # False: too small for the classifier's head, ranked without it


@dataclass
class PartSubstanceView:
    substance: str | None
    probs: dict[str, float]
    observed: bool
    network: int | None = None  # the substance network (classifier id) behind `probs`, when one is


class RankingContext:
    """What one inference run needs once: materials, their colours, the classifier."""

    def __init__(self, session: Session, store: BlobStore, method: str, classifier: m.Classifier | None,
                 settings: Settings, top_k: int, color_prior: bool = True, calibrate_substances: bool = True):
        self.store = store
        self.method = method
        self.top_k = top_k
        self.settings = settings
        mats = session.execute(
            sa.select(m.Material).where(m.Material.enabled, m.Material.status == "ok").order_by(m.Material.id)
        ).scalars().all()
        self.materials = [(mat.id, mat.substance) for mat in mats]
        self.material_substance = dict(self.materials)
        self.available_substances = {sub for _, sub in self.materials}
        self.classifier = classifier
        self.model = None
        self.bn_prior: float | None = None
        self.colour_key: dict[str, str] = {}
        if method == "classifier":
            if classifier is None or not classifier.checkpoint_blob:
                raise ValueError("no trained material classifier: run the training stage first")
            set_torch_threads(settings.torch_threads)
            record = Calibration.of(classifier)
            self.bn_prior, self.colour_key = record.bn_prior, record.colour_key
            self.model = load_classifier(store.read_bytes(classifier.checkpoint_blob), device=settings.device,
                                         bn_prior=self.bn_prior)
        self.material_labs: dict[int, np.ndarray] = {}
        if method == "color-match":
            for mat in mats:
                lab = material_lab(mat, store)
                if lab is not None:
                    self.material_labs[mat.id] = lab
        self.color_sigma: float | None = None
        self.evidence: ClassifierEvidence | None = None
        if self.model is not None:
            assert classifier is not None
            # materials disabled since training can neither be chosen nor lend their substance mass
            self.evidence = stored_evidence(session, store, classifier, self.model,
                                            enabled=frozenset(self.material_substance), color=color_prior)
            if self.evidence.color_prior is not None:
                self.color_sigma = self.evidence.color_prior[1]
            elif color_prior:
                log.warning("classifier %s: no stored colour sigma (the training stage fits it) or no material "
                            "colours: ranking without the colour likelihood", classifier.id)
        # part-level temperature of each substance network whose rows weight the ranking (fit by training)
        self.substance_temperatures: dict[int, float | None] = {}
        if method == "classifier" and calibrate_substances:
            for network in substance_networks(session):
                self.substance_temperatures[network] = stored_temperature(session, network)

    @property
    def params(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "classifier": self.classifier.id if (self.classifier and self.method == "classifier") else None,
            "top_k": self.top_k,
            "materials": [mid for mid, _ in self.materials],
            "code": CODE_VERSION,
            "color_sigma": None if self.color_sigma is None else round(self.color_sigma, 4),
            "substance_temperatures": {str(k): None if v is None else round(v, 4)
                                       for k, v in sorted(self.substance_temperatures.items())},
            # only when chosen: rows ranked without adaptation keep their hashes
            **({} if self.bn_prior is None else {"bn_prior": self.bn_prior}),
            **self.colour_key,
        }

    def substance_weights(self, view: PartSubstanceView) -> np.ndarray:
        """The part's substance confidence as ranking weights, calibrated for its network."""
        temperature = self.substance_temperatures.get(view.network) if view.network is not None else None
        return substance_vector(temper(view.probs, temperature) if temperature is not None else view.probs)


def prior_substance(session: Session, part: m.Part, pair_id: int, available: set[str]) -> tuple[str | None, dict]:
    """Substance for an unobserved part: the shape's other pairs, else the part-name prior."""
    observed = session.execute(
        sa.select(m.PartSubstance.substance).where(
            m.PartSubstance.part_id == part.id, m.PartSubstance.pair_id != pair_id,
            m.PartSubstance.observed, m.PartSubstance.substance.is_not(None),
        )
    ).scalars().all()
    prior = empirical_prior(observed) or name_prior(part.name)
    prior = restrict(prior, available)
    if not prior:
        return None, {}
    best = max(SUBSTANCES, key=lambda s: (prior.get(s, 0.0), -SUBSTANCES.index(s)))
    return best, prior


def load_part_map(store: BlobStore, alignment: m.Alignment, shape: tuple[int, int]) -> np.ndarray:
    part_map = store.load_image(alignment.crf_blob or alignment.flow_blob or alignment.coarse_blob)
    if part_map.ndim == 3:
        part_map = part_map[..., 0]
    if part_map.shape != shape:
        part_map = cv2.resize(part_map, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return part_map.astype(np.int32)


def rank_part(ctx: RankingContext, image: np.ndarray, fg: np.ndarray, item: PartInput, pair_id: int,
               batch: dict[int, tuple[np.ndarray, np.ndarray]]) -> list[RankedMaterial]:
    sub = item.substance
    if ctx.method == "no-classifier":
        seed = item_seed(pair_id, item.part.id, ctx.method)
        return random_of_substance(sub.substance, ctx.materials, seed, ctx.top_k)
    if ctx.method == "color-match":
        mask = item.mask if item.mask is not None else fg
        lab = median_lab(image, mask)
        if lab is None:
            return []
        return color_match(lab, ctx.material_labs, ctx.material_substance, ctx.top_k,
                           substance=None if item.mask is not None else sub.substance)
    # ours: the evidence of the part (classify.evidence), ranked by the one policy (classify.ranking)
    assert ctx.evidence is not None
    head = batch[item.part.id][0]
    if item.mask is not None:
        evidence = ctx.evidence.region(head, ctx.substance_weights(sub), image, item.mask, substance=sub.substance)
        if evidence.color_weights is not None:
            item.color = dict(zip(ctx.evidence.policy.materials, evidence.color_weights.tolist(), strict=True))
    else:  # unobserved: only the prior substance's materials
        evidence = ctx.evidence.unobserved(head, sub.substance)
    ranked = ctx.evidence.rank(evidence, ctx.top_k)
    item.head = ranked.head_used
    return [RankedMaterial(r.material_id, r.substance, r.score, r.posterior) for r in ranked.materials]


def part_inputs(session: Session, ctx: RankingContext, pair_id: int, parts: Sequence[m.Part],
                part_map: np.ndarray) -> list[PartInput]:
    """Each part of the pair with its mask in the aligned part map and the substance it is ranked under.

    A part with too few pixels for the classifier is unobserved (no mask); its substance is the
    substance network's when that saw it, else `prior_substance`.
    """
    substances = {
        ps.part_id: ps for ps in session.execute(
            sa.select(m.PartSubstance).where(m.PartSubstance.pair_id == pair_id)
        ).scalars()
    }
    min_pixels = max(16, int(0.0005 * part_map.size))
    items: list[PartInput] = []
    for part in parts:
        mask = part_map == part.index
        ps = substances.get(part.id)
        observed = int(mask.sum()) >= min_pixels and (ps is None or ps.observed)
        if observed and ps is not None and ps.substance:
            view = PartSubstanceView(ps.substance, dict(ps.probs or {}), True, ps.classifier_id)
        elif observed:
            # aligned but no substance row (substances stage not run): fall back to the prior
            sub, prior = prior_substance(session, part, pair_id, ctx.available_substances)
            view = PartSubstanceView(sub, prior, True)
        elif ps is not None and ps.observed and ps.substance in ctx.available_substances:
            # too small for the classifier, but the substance network saw it: its substance beats a prior
            view = PartSubstanceView(ps.substance, dict(ps.probs or {}), False, ps.classifier_id)
        else:
            sub, prior = prior_substance(session, part, pair_id, ctx.available_substances)
            view = PartSubstanceView(sub, prior, False)
        items.append(PartInput(part, mask if observed else None, view))
    return items
