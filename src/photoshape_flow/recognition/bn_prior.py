"""The networks' BatchNorm priors (`classify.bn_adapt`), chosen on photo-like validation renders.

How strongly a photo's own statistics should replace the training set's depends on how far photos
are from the training renders, which no constant knows. It is chosen like every other weight of the
ranking: on the collection's validation renders (val shapes, val envmaps), each degraded like an
exemplar at the exemplars' size (`validation_photos.as_photo`: exposure, white balance, blur, noise,
JPEG) with its part map misaligned as fine alignment errs, never on exemplars or evaluation worlds.
The candidate with the lowest mean log-loss of the truth, after its own maximum-likelihood
temperature (`region_losses`), wins if it beats no adaptation beyond noise (a paired bootstrap over
the renders, `choose`); otherwise the network reads photos as trained:

- the material classifier: the true material under the material head over the enabled materials,
  chosen by the training stage's calibration, read by inference, fit's calibration and `retrieve`;
- the substance network: the true substance under the part's mean probability (the part-level
  vote `classify.substance_parts` takes), chosen by the substances stage right after training on
  the validation renders that exist then (the bootstrap round's), read when it labels the parts.

Each is stored in its network's `metrics` as `bn_prior_choice` (the prior and every candidate's
log-loss), keyed by the checkpoint and the renders (`bn_prior_key`); `networks.calibrations.Calibration.bn_prior`
reads it back where a network is loaded.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.substance_calibration import fit_temperature
from photoshape_flow.classify.substance_recognition import substance_map
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.fit.validation import misalign, resampled, sample_misalignment
from photoshape_flow.hashing import item_seed, stable_hash
from photoshape_flow.networks.calibrations import Calibration
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.networks.validation_photos import as_photo, exemplar_size, validation_renders
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.synth.spec import RenderSpec
from photoshape_flow.vocab import SUBSTANCE_LABELS

log = logging.getLogger(__name__)

CANDIDATES: tuple[float | None, ...] = (None, 16.0, 4.0, 1.0)
RENDERS = 100  # validation renders made photo-like for each choice
MIN_PIXELS = 64  # smaller regions are not scored


@dataclass(frozen=True)
class PhotoCase:
    """A validation render seen as a photo: the image, a mask per scored part and its true material."""

    key: str
    image: np.ndarray
    masks: tuple[np.ndarray, ...]
    truth: tuple[int, ...]


def clean_photo(hdr: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """A render composited over white and sRGB-encoded, with no photographic degradation."""
    covered = (np.asarray(ids) > 0).astype(np.float32)[..., None]
    linear = np.clip(np.asarray(hdr, np.float32)[..., :3], 0, 1) * covered + (1 - covered)
    srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
    return (np.clip(srgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def photo_cases(session: sa.orm.Session, store: BlobStore, settings: Settings, count: int,
                degrade: bool = True, kinds: tuple[str, ...] = ("training", "bootstrap")) -> list[PhotoCase]:
    """Up to `count` validation renders, degraded and misaligned deterministically (seed and render key).

    `degrade=False`: the clean render with its exact part map (the classifier's own domain).
    """
    size = exemplar_size(session)
    out = []
    for row in validation_renders(session, count, settings.seed, kinds):
        truth = RenderSpec.from_dict(row.params).material_by_index()
        hdr, ids = store.load_image(row.blobs["hdr"]), store.load_image(row.blobs["part_ids"])
        ids = ids[..., 0] if ids.ndim == 3 else ids
        if size:
            hdr, ids = resampled(hdr, ids, size)
        rng = np.random.default_rng(item_seed(settings.seed, "bn-prior", row.kind, row.key))
        image = as_photo(hdr, ids, int(rng.integers(2**31 - 1))) if degrade else clean_photo(hdr, ids)
        labels = misalign(ids, sample_misalignment(rng, max(ids.shape))) if degrade else ids
        parts = [int(i) for i in np.unique(labels) if i > 0 and int(i) in truth and (labels == i).sum() >= MIN_PIXELS]
        if parts:
            out.append(PhotoCase(f"{row.kind}/{row.key}", image, tuple(labels == i for i in parts),
                                 tuple(truth[i] for i in parts)))
    return out


Readings = tuple[np.ndarray, np.ndarray, np.ndarray]  # probabilities (R, C), true column (R,), case index (R,)


def material_readings(model: Any, cases: list[PhotoCase], enabled: set[int]) -> Readings:
    """The material head over the enabled materials (renormalised) per scored region, the true column, the case."""
    columns = np.array([i + 1 for i, mid in enumerate(model.materials) if mid in enabled])
    ids = np.asarray(model.materials)[columns - 1]
    probs, truth, group = [], [], []
    for c, case in enumerate(cases):
        mats, _ = model.predict(case.image, list(case.masks))
        p = mats[:, columns]
        p = p / np.maximum(p.sum(1, keepdims=True), 1e-12)
        for k, true in enumerate(case.truth):
            where = np.nonzero(ids == true)[0]
            if len(where):
                probs.append(p[k])
                truth.append(int(where[0]))
                group.append(c)
    return (np.asarray(probs).reshape(len(probs), len(columns)), np.asarray(truth, np.int64),
            np.asarray(group, np.int64))


def region_losses(readings: Readings) -> np.ndarray:
    """-log p(truth) per region after the readings' own maximum-likelihood temperature.

    Tempered first because adaptation also flattens or sharpens a network's confidence, and the
    ranking re-calibrates confidence anyway (posterior, part temperature): what the prior should win
    on is how well the truth is told apart, not how confident the network happens to be.
    """
    probs, truth, _ = readings
    if not len(truth):
        return np.zeros(0)
    z = np.log(np.maximum(np.asarray(probs, np.float64), 1e-12)) / (fit_temperature(probs, truth) or 1.0)
    z = z - z.max(axis=1, keepdims=True)
    return np.log(np.exp(z).sum(axis=1)) - z[np.arange(len(truth)), truth]


def tempered_log_loss(readings: Readings) -> float | None:
    """The mean of `region_losses` (None: nothing read)."""
    losses = region_losses(readings)
    return float(losses.mean()) if len(losses) else None


def choose(losses: dict[float | None, np.ndarray], groups: np.ndarray, draws: int = 2000) -> float | None:
    """The prior of lowest mean loss among those that beat no adaptation beyond noise, else None.

    `losses`: per-region losses of each candidate on the same regions; `groups`: each region's case
    (validation render). A candidate counts only when the 95% bootstrap interval of its mean loss
    minus no adaptation's, resampling whole renders, lies below 0: a few dozen renders cannot tell
    small differences from chance, and a prior adopted on chance would re-label every part for
    nothing.
    """
    base = losses.get(None)
    if base is None or not len(base):
        return None
    keys, index = np.unique(np.asarray(groups), return_inverse=True)
    rng = np.random.default_rng(0)
    picks = rng.integers(0, len(keys), (draws, len(keys)))
    counts = np.stack([np.bincount(row, minlength=len(keys)) for row in picks])[:, index]  # (draws, regions)
    best: float | None = None
    best_loss = float(base.mean())
    for prior, values in losses.items():
        if prior is None or len(values) != len(base) or float(values.mean()) >= best_loss:
            continue
        diff = (counts * (values - base)).sum(1) / np.maximum(counts.sum(1), 1)
        if np.percentile(diff, 97.5) < 0:
            best, best_loss = prior, float(values.mean())
    return best


def choose_bn_prior(settings: Settings, classifier_id: int, count: int = RENDERS,
                    store: BlobStore | None = None) -> dict[str, Any]:
    """Choose (or read back) the material classifier's prior; returns {"bn_prior", "log_loss", "regions"}."""
    row, model = load_material_classifier(classifier_id, settings, store=store)
    with session_scope(settings.resolved_database_url) as session:
        enabled = set(session.execute(sa.select(m.Material.id).where(m.Material.enabled)).scalars())

    def readings(prior: float | None, cases: list[PhotoCase]) -> Readings:
        model.bn_prior = prior
        return material_readings(model, cases, enabled)

    return _choose_and_store(settings, classifier_id, row.checkpoint_blob, count, readings, store=store)


def substance_readings(network: Any, size: int, cases: list[PhotoCase], substance_of: dict[int, str],
                       prior: float | None) -> Readings:
    """Each scored part's mean substance probability (background left out, renormalised), the truth, the case."""
    probs, truth, group = [], [], []
    for c, case in enumerate(cases):
        labels = np.zeros(case.image.shape[:2], np.int32)
        for k, mask in enumerate(case.masks, start=1):
            labels[mask] = k
        pixels = substance_map(network, case.image, labels, size, bn_prior=prior)
        for mask, true in zip(case.masks, case.truth, strict=True):
            mean = pixels[1:, mask].mean(1)
            probs.append(mean / max(float(mean.sum()), 1e-12))
            truth.append(SUBSTANCE_LABELS.index(substance_of[true]) - 1)
            group.append(c)
    return (np.asarray(probs).reshape(len(probs), len(SUBSTANCE_LABELS) - 1), np.asarray(truth, np.int64),
            np.asarray(group, np.int64))


def choose_substance_bn_prior(settings: Settings, network_id: int, network: Any, size: int,
                              count: int = RENDERS, store: BlobStore | None = None) -> dict[str, Any]:
    """Choose (or read back) a substance network's prior, as `choose_bn_prior` does for the classifier."""
    with session_scope(settings.resolved_database_url) as session:
        row = session.get(m.Classifier, network_id)
        checkpoint = row.checkpoint_blob if row is not None else None
        substance_of = dict(session.execute(sa.select(m.Material.id, m.Material.substance)).all())

    def readings(prior: float | None, cases: list[PhotoCase]) -> Readings:
        return substance_readings(network, size, cases, substance_of, prior)

    # the bootstrap round's renders only: those are what exist when the stage first chooses, so a
    # re-run after the training round's renders exist reads the same ones and keeps the choice
    return _choose_and_store(settings, network_id, checkpoint, count, readings, kinds=("bootstrap",), store=store)


def _choose_and_store(settings: Settings, network_id: int, checkpoint: str | None, count: int,
                      read: Callable[[float | None, list[PhotoCase]], Readings],
                      kinds: tuple[str, ...] = ("training", "bootstrap"),
                      store: BlobStore | None = None) -> dict[str, Any]:
    store = store if store is not None else default_store(settings)
    url = settings.resolved_database_url
    with session_scope(url) as session:
        row = session.get(m.Classifier, network_id)
        stored = Calibration.of(row)
        renders = sorted(f"{r.kind}/{r.key}" for r in validation_renders(session, count, settings.seed, kinds))
        key = stable_hash({"checkpoint": checkpoint, "renders": renders, "candidates": CANDIDATES,
                           "seed": settings.seed, "rule": "tempered, beyond noise"})
        if stored.bn_prior_key == key and stored.bn_prior_choice is not None:
            return dict(stored.bn_prior_choice)
        cases = photo_cases(session, store, settings, count, kinds=kinds)
    readings = {prior: read(prior, cases) for prior in CANDIDATES}
    losses = {prior: region_losses(r) for prior, r in readings.items()}
    chosen = choose(losses, readings[None][2])
    result = {"bn_prior": chosen, "regions": int(len(readings[None][1])), "renders": len(cases),
              "log_loss": {str(p): round(float(v.mean()), 4) if len(v) else None for p, v in losses.items()},
              "top1": {str(p): round(float((r[0].argmax(1) == r[1]).mean()), 4) if len(r[1]) else None
                       for p, r in readings.items()}}
    log.info("network %d: BatchNorm prior %s chosen on %d photo-like validation regions (log-loss %s)",
             network_id, chosen, result["regions"], result["log_loss"])
    with session_scope(url) as session:
        row = session.get(m.Classifier, network_id)
        if row is not None and row.checkpoint_blob == checkpoint:
            Calibration.store(row, bn_prior_choice=result, bn_prior_key=key)
    return result
