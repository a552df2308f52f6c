"""Calibrations of the ranking's evidence, fitted before inference and stored on each network's row.

Two calibrations make the product of experts in `classify.ranking` weigh its experts right:

- the colour likelihood's material colours (each material's median colour in the training renders)
  and its sigma (how far lighting, UV scale, shading and a photo's imaging move a part's median
  colour), fit by robust maximum likelihood on validation renders seen as photos (D63), cached in
  the material classifier's `metrics` (`color_labs`, `color_sigma`, keyed by the renders, the preview
  colours, the seed and the exemplars' size);
- each substance network's part-level temperature (`recognition.substance_temperature`),
  fit on the validation renders of both rounds and cached in that network's `metrics`.

Then it checks the result: `posterior_reliability` ranks the material regions of the validation
renders through `classify.ranking` and compares the top material's posterior with how often it
is right (reliability bins and ECE, cached in the classifier's `metrics` as `posterior_ece` and
`posterior_reliability`), so a user knows what a threshold on `assignment.posterior` means.

The training stage fits both once its classifier exists (the temperature needs the training round's
validation renders too); inference and `photoshape retrieve` only read them, so ranking never
re-reads hundreds of renders and two workers never race to fit the same number.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify.color_prior import (
    fit_color_sigma,
    region_color_distances,
    region_labs,
    rendered_material_labs,
)
from photoshape_flow.classify.dataset import frame_object
from photoshape_flow.classify.evidence import ClassifierEvidence
from photoshape_flow.classify.reliability import reliability
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.hashing import item_seed, stable_hash
from photoshape_flow.imaging.io import load_label_map, load_rgb
from photoshape_flow.networks.calibrations import Calibration, fitted_labs, material_labs
from photoshape_flow.networks.classifiers import load_material_classifier, substance_networks
from photoshape_flow.networks.evidence import stored_evidence
from photoshape_flow.networks.validation_photos import calibration_photo, exemplar_size, validation_renders
from photoshape_flow.recognition.bn_prior import choose_bn_prior
from photoshape_flow.recognition.substance_temperature import substance_temperature
from photoshape_flow.recognition.training import training_data
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.synth.spec import RenderSpec

log = logging.getLogger(__name__)

COLOR_SIGMA_RENDERS = 200  # validation renders, seen as photos, that fit the colour likelihood's sigma
COLOR_LAB_RENDERS = 400  # training renders read for each material's colour
POSTERIOR_RENDERS = 200  # validation renders whose regions measure the posterior's reliability


def fit_color_evidence(
    session: Session, store: BlobStore, settings: Settings, material_labs: dict[int, np.ndarray],
    classifier: m.Classifier | None = None,
) -> tuple[dict[int, np.ndarray], float | None]:
    """(material colours, sigma) of the colour likelihood; sigma None when no validation render has a region.

    The colours are `color_prior.rendered_material_labs` over the training split's renders, the
    preview's (`material_labs`) where a material has too few regions there; sigma is fit on the
    distances of validation renders seen as the pipeline sees a photo (`calibration_photo`: at the
    exemplars' size, degraded, framed, misaligned), so it measures what a photo's part does (D63).
    With `classifier`, both are cached in its `metrics` (`color_labs`, `color_sigma`, keyed by the
    renders, the preview colours, the seed and the exemplars' size), so `photoshape retrieve` and later
    inference runs do not re-read hundreds of renders; the caller's session commits it.
    """
    data = training_data(session, store)
    size = exemplar_size(session)
    key = stable_hash({"renders": data.hash, "limit": COLOR_SIGMA_RENDERS, "colours": COLOR_LAB_RENDERS,
                       "scheme": "rendered colours, photo-like sigma", "seed": settings.seed, "size": size,
                       "labs": {str(k): np.round(v, 3).tolist() for k, v in sorted(material_labs.items())}})
    stored = Calibration.of(classifier)
    if classifier is not None and stored.color_sigma_key == key:
        return {**material_labs, **fitted_labs(stored)}, stored.color_sigma
    rendered = {mid: lab for mid, lab in rendered_material_labs(data.train, limit=COLOR_LAB_RENDERS).items()
                if mid in material_labs}
    labs = {**material_labs, **rendered}
    distances = photo_color_distances(session, store, settings.seed, labs, size)
    source = "validation renders seen as photos"
    if not len(distances):  # renders kept without their HDR and spec (toy or imported sets): read as stored
        distances = region_color_distances(data.val, labs, limit=COLOR_SIGMA_RENDERS)
        source = "stored validation images (no HDR kept to make photos of)"
    sigma = fit_color_sigma(distances)
    log.info("colour likelihood: %d of %d material colours from the training renders, sigma %s (CIELAB, fit on "
             "%d part distances in %s)", len(rendered), len(labs), f"{sigma:.2f}" if sigma else "none",
             len(distances), source)
    if classifier is not None:
        Calibration.store(classifier, color_sigma=sigma, color_sigma_key=key,
                          color_labs={str(k): np.round(v, 3).tolist() for k, v in sorted(rendered.items())})
    return labs, sigma


def photo_color_distances(session: Session, store: BlobStore, seed: int, labs: dict[int, np.ndarray],
                          size: int | None, limit: int = COLOR_SIGMA_RENDERS) -> np.ndarray:
    """CIE76 distance of each part of a sample of validation renders, seen as photos, from its material's colour.

    The renders are `validation_renders`' sample; each becomes `calibration_photo` at the exemplars'
    size (seeded by its key), and each misaligned part of at least 0.5% of the photo (the classifier's
    default smallest region) whose true material has a colour gives one distance.
    """
    distances: list[float] = []
    for row in validation_renders(session, limit, seed):
        truth = RenderSpec.from_dict(row.params).material_by_index()
        try:
            hdr, ids = store.load_image(row.blobs["hdr"]), store.load_image(row.blobs["part_ids"])
        except (OSError, ValueError) as exc:
            log.warning("%s/%s: %s; not used for the colour sigma", row.kind, row.key, exc)
            continue
        ids = ids[..., 0] if ids.ndim == 3 else ids
        rng = np.random.default_rng(item_seed(seed, "colour-sigma", row.kind, row.key))
        rgb, labels, _ = calibration_photo(hdr, ids, size, size or max(ids.shape), rng)
        distances += [float(np.linalg.norm(lab - labs[truth[value]])) for value, lab in region_labs(rgb, labels)
                      if truth.get(value) in labs]
    return np.asarray(distances, np.float64)


def calibrate(settings: Settings, classifier_id: int, store: BlobStore | None = None) -> dict[str, Any]:
    """Fit (or confirm the cached) colour sigma of a material classifier and every substance temperature."""
    store = store if store is not None else default_store(settings)
    with session_scope(settings.resolved_database_url) as session:
        classifier = session.get(m.Classifier, classifier_id)
        if classifier is None:
            raise LookupError(f"no classifier with id {classifier_id}")
        labs = material_labs(session, store, [int(x) for x in classifier.materials if int(x) != 0])
        sigma = fit_color_evidence(session, store, settings, labs, classifier)[1] if labs else None
        networks = substance_networks(session)
    temperatures = {str(n): substance_temperature(settings, n, store) for n in networks}
    bn_prior = choose_bn_prior(settings, classifier_id, store=store)
    return {"color_sigma": sigma, "substance_temperatures": temperatures, "bn_prior": bn_prior,
            "posterior": posterior_reliability(settings, classifier_id, store=store)}


def posterior_reliability(settings: Settings, classifier_id: int, limit: int = POSTERIOR_RENDERS,
                          store: BlobStore | None = None) -> dict[str, Any]:
    """Reliability of the ranking's posterior on the validation renders' material regions (cached).

    Each region (at least the classifier's smallest training region) is ranked as inference ranks an
    observed part: the material head, the colour likelihood with the stored sigma, and as substance
    evidence the classifier's own substance head (the substance network is not re-run on renders).
    The top material's posterior against whether it is the region's true material gives the bins
    and the ECE (`classify.reliability`), stored in the classifier's `metrics` and keyed by the
    checkpoint, the renders and the sigma, so a re-run of training that changes none reads them back.
    """
    store = store if store is not None else default_store(settings)
    url = settings.resolved_database_url
    row, model = load_material_classifier(classifier_id, settings, store=store)
    with session_scope(url) as session:
        data = training_data(session, store)
        classifier = session.get(m.Classifier, classifier_id)
        assert classifier is not None
        stored = Calibration.of(classifier)
        key = stable_hash({"checkpoint": row.checkpoint_blob, "renders": data.hash, "limit": limit,
                           "sigma": stored.color_sigma,
                           **({"bn_prior": prior} if (prior := stored.bn_prior) is not None else {})})
        if stored.posterior_key == key and stored.posterior_reliability is not None:
            return dict(stored.posterior_reliability)
        enabled = frozenset(session.execute(sa.select(m.Material.id).where(m.Material.enabled)).scalars())
        evidence = stored_evidence(session, store, classifier, model, enabled=enabled)
    framed = bool((row.config or {}).get("frame_object"))
    confidence, correct = _ranked_regions(model, evidence, data.val[:limit], framed)
    result = reliability(np.asarray(confidence), np.asarray(correct)).to_dict()
    log.info("classifier %d: posterior ECE %s on %d validation regions (accuracy %s, mean posterior %s)",
             classifier_id, result["ece"], result["regions"], result["accuracy"], result["mean_posterior"])
    with session_scope(url) as session:
        classifier = session.get(m.Classifier, classifier_id)
        if classifier is not None and classifier.checkpoint_blob == row.checkpoint_blob:
            Calibration.store(classifier, posterior_reliability=result, posterior_key=key)
    return result


def _ranked_regions(model: Any, evidence: ClassifierEvidence, items: Sequence[Any],
                    framed: bool) -> tuple[list[float], list[bool]]:
    """(top posterior, right?) of every large-enough material region of `items`; unreadable renders skipped."""
    confidence: list[float] = []
    correct: list[bool] = []
    known = set(model.materials)
    policy = evidence.policy
    for item in items:
        try:
            image, ids = load_rgb(item.image), load_label_map(item.material_map)
        except (OSError, ValueError) as exc:
            log.warning("%s: %s; not used for the posterior check", item.key, exc)
            continue
        if framed:
            image, ids = frame_object(image, ids)
        minimum = max(16, int(np.ceil(policy.min_region_fraction * ids.size)))
        values, counts = np.unique(ids, return_counts=True)
        regions = [int(v) for v, n in zip(values.tolist(), counts.tolist(), strict=True)
                   if v in known and (policy.enabled is None or v in policy.enabled) and n >= minimum]
        if not regions:
            continue
        masks = [ids == v for v in regions]
        mats, subs = model.predict(image, masks)
        for material, ranked in zip(regions, evidence.rank_regions(image, masks, mats, subs, 1), strict=True):
            top = ranked.materials
            if top:
                confidence.append(top[0].posterior)
                correct.append(top[0].material_id == material)
    return confidence, correct
