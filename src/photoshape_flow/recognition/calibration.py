"""Calibrations of the ranking's evidence, fitted before inference and stored on each network's row.

Two numbers make the product of experts in `classify.ranking` weigh its experts right:

- the colour likelihood's sigma (how far lighting, UV scale and shading move a material's median
  colour), fit by robust maximum likelihood on the validation training renders, cached in the
  material classifier's `metrics` (`color_sigma`, keyed by those renders and the material colours);
- each substance network's part-level temperature (`pipeline.substances.substance_temperature`),
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

from photoshape_flow.classify.assignment import foreground_of_render, median_lab
from photoshape_flow.classify.color_prior import fit_color_sigma, material_lab_matrix, region_color_distances
from photoshape_flow.classify.dataset import frame_object
from photoshape_flow.classify.evidence import ClassifierEvidence
from photoshape_flow.classify.reliability import reliability
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.hashing import stable_hash
from photoshape_flow.imaging.io import load_label_map, load_rgb
from photoshape_flow.recognition.bn_prior import choose_bn_prior
from photoshape_flow.recognition.substances import substance_temperature
from photoshape_flow.recognition.training import load_material_classifier, stored_bn_prior, training_data
from photoshape_flow.store import BlobStore, default_store

log = logging.getLogger(__name__)

COLOR_SIGMA_RENDERS = 400  # validation renders read to fit the colour likelihood's sigma
POSTERIOR_RENDERS = 200  # validation renders whose regions measure the posterior's reliability


def fit_classifier_color_sigma(
    session: Session, store: BlobStore, material_labs: dict[int, np.ndarray],
    classifier: m.Classifier | None = None,
) -> float | None:
    """sigma of the colour likelihood from the validation renders (None when there are none).

    With `classifier`, the fit is cached in its `metrics` (`color_sigma`, keyed by the validation
    renders and the material colours), so `photoshape retrieve` and later inference runs do not
    re-read hundreds of renders; the caller's session commits it.
    """
    data = training_data(session, store)
    key = stable_hash({"renders": data.hash, "limit": COLOR_SIGMA_RENDERS,
                       "labs": {str(k): np.round(v, 3).tolist() for k, v in sorted(material_labs.items())}})
    metrics = dict(classifier.metrics or {}) if classifier is not None else {}
    if classifier is not None and metrics.get("color_sigma_key") == key:
        cached = metrics.get("color_sigma")
        return None if cached is None else float(cached)
    sigma = fit_color_sigma(region_color_distances(data.val, material_labs, limit=COLOR_SIGMA_RENDERS))
    log.info("colour likelihood sigma %s (CIELAB, fit on %d validation renders)",
             f"{sigma:.2f}" if sigma else "none", min(len(data.val), COLOR_SIGMA_RENDERS))
    if classifier is not None:
        classifier.metrics = {**metrics, "color_sigma": sigma, "color_sigma_key": key}
    return sigma


def material_labs(session: Session, store: BlobStore, materials: Sequence[int]) -> dict[int, np.ndarray]:
    """Median CIELAB colour of each of `materials` that has one (`material_lab`)."""
    rows = session.execute(sa.select(m.Material).where(m.Material.id.in_([int(x) for x in materials]))).scalars()
    return {mat.id: lab for mat in rows if (lab := material_lab(mat, store)) is not None}


def material_lab(material: m.Material, store: BlobStore) -> np.ndarray | None:
    """Median CIELAB colour of a material's render (its preview), else of its albedo."""
    if material.preview_blob and store.exists(material.preview_blob):
        image = store.load_image(material.preview_blob)
        alpha = image[..., 3] / 255.0 if image.ndim == 3 and image.shape[2] == 4 else None
        rgb = image[..., :3]
        if rgb.dtype != np.uint8:
            rgb = (np.clip(rgb.astype(np.float64) / np.iinfo(rgb.dtype).max, 0, 1) * 255).astype(np.uint8)
        return median_lab(rgb, foreground_of_render(rgb, alpha))
    albedo = (material.maps or {}).get("albedo")
    if albedo and store.exists(albedo):
        return median_lab(store.load_image(albedo)[..., :3])
    color = (material.params or {}).get("albedo")
    if color is not None:
        rgb = (np.clip(np.asarray(color, np.float64), 0, 1) * 255).astype(np.uint8).reshape(1, 1, 3)
        return median_lab(rgb)
    return None


def stored_color_prior(
    session: Session, store: BlobStore, materials: Sequence[int], classifier: m.Classifier
) -> tuple[np.ndarray, float] | None:
    """(material colours in `materials` order, the classifier's stored sigma); None when not calibrated."""
    sigma = (classifier.metrics or {}).get("color_sigma")
    if sigma is None:
        return None
    labs = material_labs(session, store, materials)
    return (material_lab_matrix(materials, labs), float(sigma)) if labs else None


def stored_temperature(session: Session, network_id: int) -> float | None:
    """A substance network's stored part-level temperature (None: not fitted, or too few parts)."""
    row = session.get(m.Classifier, network_id)
    value = (row.metrics or {}).get("part_temperature") if row is not None else None
    return None if value is None else float(value)


def substance_networks(session: Session) -> list[int]:
    """The substance networks whose part substances weight the ranking."""
    return sorted(int(n) for n in session.execute(
        sa.select(m.PartSubstance.classifier_id).where(m.PartSubstance.classifier_id.is_not(None)).distinct()
    ).scalars())


def calibrate(settings: Settings, classifier_id: int, store: BlobStore | None = None) -> dict[str, Any]:
    """Fit (or confirm the cached) colour sigma of a material classifier and every substance temperature."""
    store = store if store is not None else default_store(settings)
    with session_scope(settings.resolved_database_url) as session:
        classifier = session.get(m.Classifier, classifier_id)
        if classifier is None:
            raise LookupError(f"no classifier with id {classifier_id}")
        labs = material_labs(session, store, [int(x) for x in classifier.materials if int(x) != 0])
        sigma = fit_classifier_color_sigma(session, store, labs, classifier) if labs else None
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
        metrics = dict(classifier.metrics or {})
        key = stable_hash({"checkpoint": row.checkpoint_blob, "renders": data.hash, "limit": limit,
                           "sigma": metrics.get("color_sigma"),
                           **({"bn_prior": prior} if (prior := stored_bn_prior(classifier)) is not None else {})})
        if metrics.get("posterior_key") == key and "posterior_reliability" in metrics:
            return dict(metrics["posterior_reliability"])
        prior = stored_color_prior(session, store, model.materials, classifier)
        enabled = frozenset(session.execute(sa.select(m.Material.id).where(m.Material.enabled)).scalars())
    evidence = ClassifierEvidence.for_classifier(model, row.config, enabled=enabled, color_prior=prior)
    framed = bool((row.config or {}).get("frame_object"))
    confidence, correct = _ranked_regions(model, evidence, data.val[:limit], framed)
    result = reliability(np.asarray(confidence), np.asarray(correct)).to_dict()
    log.info("classifier %d: posterior ECE %s on %d validation regions (accuracy %s, mean posterior %s)",
             classifier_id, result["ece"], result["regions"], result["accuracy"], result["mean_posterior"])
    with session_scope(url) as session:
        classifier = session.get(m.Classifier, classifier_id)
        if classifier is not None and classifier.checkpoint_blob == row.checkpoint_blob:
            classifier.metrics = {**(classifier.metrics or {}), "posterior_ece": result["ece"],
                                  "posterior_reliability": result, "posterior_key": key}
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
