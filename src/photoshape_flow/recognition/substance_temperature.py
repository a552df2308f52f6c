"""A substance network's part-level temperature (`classify.substance_calibration`), fitted by the
training stage on held-out renders and stored in its row's calibrations (`Calibration.part_temperature`)."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.substance_calibration import fit_temperature, nll, part_calibration_set
from photoshape_flow.classify.substance_configs import read_side_of
from photoshape_flow.classify.substance_recognition import substance_map
from photoshape_flow.config import Settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.hashing import stable_hash
from photoshape_flow.networks.calibrations import Calibration
from photoshape_flow.networks.classifiers import load_substance_network
from photoshape_flow.recognition.substances import load_label_blob, resize_probs
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_OK

log = logging.getLogger(__name__)

CALIBRATION_RENDERS = 600  # renders read to fit the part-level temperature (evenly spread over those held out)
CALIBRATION_KINDS: tuple[str, ...] = ("bootstrap", "training")  # rounds whose validation renders calibrate


def calibration_renders(session: sa.orm.Session, limit: int = CALIBRATION_RENDERS) -> list[tuple[str, dict]]:
    """(key, blobs) of validation renders of every round: shapes and envmaps the network never saw.

    The split is by shape and envmap and the same in every round, so the later rounds' validation
    renders are as unseen as the bootstrap's (their training renders are not: they show the shapes
    the network trained on, and would make it look better calibrated than it is on new shapes).
    At most `limit`, evenly spread over the sorted keys (every round represented, the choice stable).
    """
    rows = session.execute(
        sa.select(m.Rendering.kind, m.Rendering.key, m.Rendering.blobs)
        .where(m.Rendering.status == STATUS_OK, ~m.Rendering.exclude, m.Rendering.split == "val",
               m.Rendering.kind.in_(CALIBRATION_KINDS))
        .order_by(m.Rendering.kind, m.Rendering.key)
    ).all()
    if len(rows) > limit:
        rows = [rows[i] for i in np.linspace(0, len(rows) - 1, limit).round().astype(int)]
    return [(f"{kind}/{key}", blobs or {}) for kind, key, blobs in rows]


def substance_temperature(settings: Settings, classifier_id: int, store: BlobStore | None = None) -> float | None:
    """Part-level temperature of a substance network (`classify.substance_calibration`).

    Fit on renders of shapes and envmaps the network never trained on (`calibration_renders`: the
    validation renders of the bootstrap and training rounds, with exact part and substance labels)
    and cached in its row's `metrics` (`part_temperature`, the parts used, part accuracy and NLL
    before and after, and a key of the renders used): refit only when those renders change, and
    a retrained network writes new metrics. None: too few parts to fit (the raw confidence is used).
    """
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    with session_scope(url) as session:
        row = session.get(m.Classifier, classifier_id)
        if row is None or row.kind != "substance" or not row.checkpoint_blob:
            return None
        stored = Calibration.of(row)
        renders = calibration_renders(session)
        bn_prior = stored.bn_prior  # the parts were labelled with it: calibrate what they saw
        cache_key = stable_hash([row.checkpoint_blob, [key for key, _ in renders],
                                 *([] if bn_prior is None else [bn_prior])])
        if stored.part_temperature_key == cache_key:
            return stored.part_temperature
        size = read_side_of(row.config) or 128
        checkpoint_ref = row.checkpoint_blob
        session.expunge(row)
    model = load_substance_network(row, store, settings.device)  # outside the session: a blob read
    predictions = []
    for key, blobs in renders:
        try:
            image = store.load_image(blobs["beauty"])
            part_ids = load_label_blob(store, blobs["part_ids"]).astype(np.int64)
            substance_ids = load_label_blob(store, blobs["substance_ids"]).astype(np.int64)
            probs = substance_map(model, image[..., :3], part_ids, size, bn_prior=bn_prior)
            if probs.shape[1:] != part_ids.shape:
                probs = resize_probs(probs, part_ids.shape)
        except (KeyError, OSError, ValueError) as exc:
            log.warning("rendering %s: %s; not used for calibration", key, exc)
            continue
        predictions.append((probs, part_ids, substance_ids))
    calibration = part_calibration_set(predictions)
    temperature = fit_temperature(calibration.probs, calibration.truth)
    stats: dict[str, Any] = {"part_temperature_parts": len(calibration), "part_temperature_renders": len(predictions)}
    if len(calibration):
        stats["part_accuracy"] = float((calibration.probs.argmax(axis=1) == calibration.truth).mean())
        stats["part_nll"] = nll(calibration.probs, calibration.truth)
        stats["part_nll_tempered"] = nll(calibration.probs, calibration.truth, temperature or 1.0)
    with session_scope(url) as session:
        row = session.get(m.Classifier, classifier_id)
        if row is not None and row.checkpoint_blob == checkpoint_ref:
            Calibration.store(row, part_temperature=temperature, part_temperature_key=cache_key, part_stats=stats)
    log.info("substance network %s: part temperature %s from %d parts of %d held-out renders", classifier_id,
             "none" if temperature is None else f"{temperature:.3f}", len(calibration), len(predictions))
    return temperature


