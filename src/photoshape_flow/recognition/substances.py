"""Stage: substances (section 4.3) — bootstrap renders, substance network, a substance per aligned part.

1. Bootstrap renders (`run_training_renders("bootstrap", ...)`): synthetic chairs whose part
   substances are drawn without exemplar evidence, with exact per-pixel substance labels.
2. The substance segmentation network (`classify.substance_net`, our stand-in for MINC) trains on
   them, or resumes: one Classifier row (kind "substance", name ``substance-<preset>``) whose
   checkpoint blob, epoch and validation metrics (pixel accuracy, per-class IoU) are updated after
   every epoch, status "training" until the last epoch, then "ok". The row's `params_hash` covers the
   preset and the exact set of bootstrap renders; when it changes the network retrains from scratch.
3. For every pair with an ok fine alignment (method "flow-crf", `crf_blob` = aligned part map, uint16
   PNG or .npy, in the frame of the exemplar's stored square crop at any resolution: the probabilities
   are resized to it) the exemplar's per-pixel substance probabilities are predicted and
   each part of the shape gets a PartSubstance row (`classify.substance_parts`: majority overlap,
   confidence, unobserved parts recorded as such).

``PartSubstance.probs`` (what inference weights the material classifier with): one float per
substance name (the mean over the part's pixels of p(substance | foreground); they sum to 1 and
`confidence` is the winner's entry; empty for unobserved parts), ``background`` (the mean raw
background probability over the part) and ``map_blob``: the exemplar's whole substance probability
map, a float16 ``.npy`` blob (6, H, W) in SUBSTANCE_LABELS order at the part map's resolution, shared
by every part of the pair (the blob store dedupes it).

Incremental and idempotent: a pair is skipped when all its parts' rows carry the current
`params_hash` (classifier checkpoint, alignment map, exemplar image, rule version).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np
import sqlalchemy as sa

from photoshape_flow.classify.substance_configs import SubstanceTrainConfig, get_config, read_side_of
from photoshape_flow.classify.substance_parts import part_substances
from photoshape_flow.classify.substance_recognition import recogniser_config, substance_map
from photoshape_flow.classify.substance_train import (
    SubstanceData,
    checkpoint_from_bytes,
    checkpoint_to_bytes,
    load_model,
    train_substance_net,
)
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.devices import resolve_device, set_torch_threads
from photoshape_flow.faults import fault_point
from photoshape_flow.hashing import stable_hash
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.progress_sink import Progress, counted, no_progress
from photoshape_flow.recognition.bn_prior import choose_substance_bn_prior
from photoshape_flow.recognition.training import run_training
from photoshape_flow.recognition.training_renders import run_training_renders
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, SUBSTANCE_LABELS

log = logging.getLogger(__name__)

ALIGNMENT_METHOD = "flow-crf"
STATUS_TRAINING = "training"
RULE_VERSION = "part-substances-v2"  # v2: flip-averaged substance probabilities


# -- training ----------------------------------------------------------------------------------------


def load_bootstrap_data(session: sa.orm.Session, store: BlobStore) -> tuple[Any, Any, str]:
    """(train, val, data_hash): ok bootstrap renders as SubstanceData, split by their `split`."""
    rows = session.execute(
        sa.select(m.Rendering.key, m.Rendering.split, m.Rendering.blobs, m.Rendering.params_hash)
        .where(m.Rendering.kind == "bootstrap", m.Rendering.status == STATUS_OK, ~m.Rendering.exclude)
        .order_by(m.Rendering.key)
    ).all()
    parts: dict[str, tuple[list[np.ndarray], list[np.ndarray], list[str], list[np.ndarray | None]]] = {
        "train": ([], [], [], []), "val": ([], [], [], [])
    }
    signature = []
    for key, split, blobs, params_hash in rows:
        blobs = blobs or {}
        beauty, labels = blobs.get("beauty"), blobs.get("substance_ids")
        if not beauty or not labels:
            log.warning("bootstrap rendering %s: no beauty or substance_ids blob; skipped", key)
            continue
        try:
            image = store.load_image(beauty)[..., :3]
            label = load_label_blob(store, labels)
            part_map = load_label_blob(store, blobs["part_ids"]) if blobs.get("part_ids") else None
        except (OSError, ValueError) as exc:
            log.warning("bootstrap rendering %s: %s; skipped", key, exc)
            continue
        target = parts["val" if split == "val" else "train"]
        target[0].append(image)
        target[1].append(label.astype(np.uint8))
        target[2].append(key)
        target[3].append(part_map)
        signature.append([key, params_hash])
    train, val = (_substance_data(*parts[name]) for name in ("train", "val"))
    return train, val, stable_hash(signature)


def _substance_data(images: list[np.ndarray], labels: list[np.ndarray], keys: list[str],
                    part_maps: list[np.ndarray | None]) -> SubstanceData:
    """SubstanceData with the part maps when every render has one (renders of older rounds may not)."""
    known = [p for p in part_maps if p is not None]
    return SubstanceData(images, labels, keys, known if len(known) == len(part_maps) else None)


def load_label_blob(store: BlobStore, ref: str) -> np.ndarray:
    array = store.load_array(ref) if ref.endswith(".npy") else store.load_image(ref)
    if array.ndim != 2:
        raise ValueError(f"blob {ref}: label map must be single-channel, got shape {array.shape}")
    return array


def train_or_resume(
    settings: Settings, train_config: str | SubstanceTrainConfig = "cpu", *, progress: Progress | None = None,
    store: BlobStore | None = None, **overrides: Any,
) -> tuple[int, Any, dict[str, Any]]:
    """Train the substance network (or resume / reuse it); returns (classifier_id, model, info)."""
    set_torch_threads(settings.torch_threads)
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    device = resolve_device(settings.device)
    base = train_config if isinstance(train_config, SubstanceTrainConfig) else get_config(train_config)
    config = replace(base, **{"device": device, "seed": base.seed or settings.seed, **overrides})
    if config.uses_backbone:
        return train_recogniser(settings, config, progress=progress, store=store)
    name = f"substance-{config.preset}"
    with session_scope(url) as session:
        train, val, data_hash = load_bootstrap_data(session, store)
        if len(train) == 0:
            raise ValueError("no usable bootstrap renders: run the bootstrap round first")
        # the device does not change the result's meaning, so it stays out of the hash
        params_hash = stable_hash({"config": {**config.to_dict(), "device": None}, "data": data_hash})
        row = session.execute(sa.select(m.Classifier).where(m.Classifier.name == name)).scalar_one_or_none()
        checkpoint = None
        if row is not None and row.params_hash == params_hash and row.checkpoint_blob:
            checkpoint = checkpoint_from_bytes(store.read_bytes(row.checkpoint_blob))
        elif row is not None:
            log.info("substance network %s: inputs changed, training from scratch", name)
        finished = checkpoint is not None and int(checkpoint["epoch"]) >= config.epochs
        if finished and row is not None and row.status == STATUS_OK:
            classifier_id = row.id  # up to date: nothing to write
        else:
            classifier_id = upsert(
                session,
                m.Classifier,
                {
                    "name": name, "kind": "substance", "architecture": config.architecture,
                    "config": config.to_dict(), "materials": list(SUBSTANCE_LABELS), "params_hash": params_hash,
                    **({} if checkpoint is not None else {"checkpoint_blob": None, "epoch": 0, "metrics": {}}),
                    "status": STATUS_OK if finished else STATUS_TRAINING,
                    "error": None,
                },
                key=["name"],
            )[0]
    info: dict[str, Any] = {
        "classifier_id": classifier_id, "name": name, "train_images": len(train), "val_images": len(val),
        "resumed_from_epoch": 0 if checkpoint is None else int(checkpoint["epoch"]), "device": device,
    }
    if finished:
        info.update(epochs_run=[], metrics=checkpoint.get("metrics", {}))
        return classifier_id, load_model(checkpoint, device), info

    report = progress or no_progress
    report("substances network epochs", int(info["resumed_from_epoch"]), config.epochs)

    def save(ckpt: dict[str, Any], metrics: dict[str, Any]) -> None:
        report("substances network epochs", int(ckpt["epoch"]), config.epochs)
        ref = store.put_bytes(checkpoint_to_bytes(ckpt), "pt")
        with session_scope(url) as session:
            session.execute(
                sa.update(m.Classifier)
                .where(m.Classifier.id == classifier_id)
                .values(
                    checkpoint_blob=ref, epoch=int(ckpt["epoch"]), metrics=metrics,
                    status=STATUS_OK if ckpt["epoch"] >= config.epochs else STATUS_TRAINING,
                )
            )
        fault_point("substance-checkpoint-saved")

    try:
        result = train_substance_net(train, val if len(val) else None, config, checkpoint=checkpoint, on_epoch=save)
    except BaseException as exc:  # Ctrl-C too: never left "training" (a re-run resumes from the checkpoint)
        with session_scope(url) as session:
            session.execute(
                sa.update(m.Classifier)
                .where(m.Classifier.id == classifier_id)
                .values(status=STATUS_FAILED, error=f"{type(exc).__name__}: {exc}"[:2000])
            )
        raise
    info.update(epochs_run=result.epochs_run, metrics=result.checkpoint.get("metrics", {}))
    return classifier_id, result.model, info


def train_recogniser(settings: Settings, config: SubstanceTrainConfig, *, progress: Progress | None = None,
                     store: BlobStore | None = None) -> tuple[int, Any, dict[str, Any]]:
    """The part recogniser on the bootstrap round (trained, resumed or reused by the training code)."""
    classifier_config = recogniser_config(config)
    classifier_id = run_training(classifier_config, settings=settings, kinds=("bootstrap",), progress=progress,
                                 network_kind="substance", store=store)
    row, model = load_material_classifier(classifier_id, settings, kind="substance", store=store)
    info = {"classifier_id": classifier_id, "name": row.name, "architecture": row.architecture,
            "metrics": {k: v for k, v in (row.metrics or {}).items() if k in ("sub@1", "mtl@1", "epochs")},
            "device": str(model.device)}
    return classifier_id, model, info


# -- part substances ----------------------------------------------------------------------------------


def assign_part_substances(
    settings: Settings, classifier_id: int, model: Any, size: int, *, min_pixels: int = 1,
    bn_prior: float | None = None, progress: Progress | None = None, store: BlobStore | None = None,
) -> dict[str, Any]:
    """PartSubstance rows for every pair with an ok flow-crf alignment (skipping up-to-date pairs).

    `bn_prior`: the network reads each photo with its BatchNorm statistics mixed with the photo's
    (`classify.bn_adapt`, chosen by `recognition.bn_prior`; None: as trained).
    """
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    summary = {"pairs": 0, "updated": 0, "skipped": 0, "failed": 0, "parts": 0, "unobserved": 0, "errors": [],
               "read_size": size}
    with session_scope(url) as session:
        classifier = session.get(m.Classifier, classifier_id)
        checkpoint_ref = classifier.checkpoint_blob if classifier else None
        todo = session.execute(
            sa.select(m.Pair.id, m.Pair.shape_id, m.Alignment.crf_blob, m.Alignment.params_hash,
                      m.Exemplar.image_blob)
            .join(m.Alignment, m.Alignment.pair_id == m.Pair.id)
            .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
            .where(
                m.Alignment.method == ALIGNMENT_METHOD, m.Alignment.status == STATUS_OK,
                m.Alignment.crf_blob.is_not(None), ~m.Pair.exclude, ~m.Exemplar.exclude,
            )
            .order_by(m.Pair.id)
        ).all()
        parts_of: dict[int, list[tuple[int, int]]] = {}
        for part_id, shape_id, index in session.execute(
            sa.select(m.Part.id, m.Part.shape_id, m.Part.index).order_by(m.Part.shape_id, m.Part.index)
        ):
            parts_of.setdefault(shape_id, []).append((part_id, index))
        current: dict[int, dict[int, str]] = {}
        for pair_id, part_id, params_hash in session.execute(
            sa.select(m.PartSubstance.pair_id, m.PartSubstance.part_id, m.PartSubstance.params_hash)
        ):
            current.setdefault(pair_id, {})[part_id] = params_hash

    for pair_id, shape_id, crf_blob, alignment_hash, image_blob in counted(progress, "substances pairs", todo):
        summary["pairs"] += 1
        parts = parts_of.get(shape_id, [])
        params_hash = stable_hash(
            {"rule": RULE_VERSION, "classifier": checkpoint_ref, "size": size, "min_pixels": min_pixels,
             "part_map": crf_blob, "alignment": alignment_hash, "image": image_blob,
             **({} if bn_prior is None else {"bn_prior": bn_prior})}
        )
        have = current.get(pair_id, {})
        if parts and all(have.get(part_id) == params_hash for part_id, _ in parts):
            summary["skipped"] += 1
            continue
        try:
            if not image_blob:
                raise ValueError("exemplar has no image blob")
            part_map = load_label_blob(store, crf_blob).astype(np.int64)
            image = store.load_image(image_blob)
            if image.ndim == 2:
                image = np.repeat(image[..., None], 3, axis=2)
            probs = substance_map(model, image[..., :3], part_map, size, bn_prior=bn_prior)
            if probs.shape[1:] != part_map.shape:
                probs = resize_probs(probs, part_map.shape)
            results = part_substances(part_map, probs, [index for _, index in parts], min_pixels=min_pixels)
        except Exception as exc:
            message = f"pair {pair_id}: {type(exc).__name__}: {exc}"
            log.warning("part substances failed: %s", message)
            summary["failed"] += 1
            summary["errors"].append(message)
            continue
        map_ref = store.put_array(probs.astype(np.float16))
        rows = []
        for (part_id, _index), result in zip(parts, results, strict=True):
            rows.append(
                {
                    "pair_id": pair_id, "part_id": part_id, "classifier_id": classifier_id,
                    "observed": result.observed, "substance": result.substance, "confidence": result.confidence,
                    "pixel_count": result.pixel_count,
                    "probs": part_probs(result, map_ref),
                    "params_hash": params_hash,
                }
            )
            summary["unobserved"] += int(not result.observed)
        with session_scope(url) as session:
            upsert(session, m.PartSubstance, rows, key=["pair_id", "part_id"])
        summary["updated"] += 1
        summary["parts"] += len(rows)
    summary["errors"] = summary["errors"][:20]
    return summary


def part_probs(result: Any, map_ref: str) -> dict[str, Any]:
    """PartSubstance.probs: substance -> probability (floats), plus the mean background and the map ref."""
    probs: dict[str, Any] = {name: float(value) for name, value in (result.probs or {}).items()}
    if result.background_prob is not None:
        probs["background"] = float(result.background_prob)
    probs["map_blob"] = map_ref
    return probs


def resize_probs(probs: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    import cv2

    h, w = int(shape[0]), int(shape[1])
    out = np.stack([cv2.resize(c, (w, h), interpolation=cv2.INTER_LINEAR) for c in probs.astype(np.float32)])
    return out / np.maximum(out.sum(axis=0, keepdims=True), 1e-8)


# -- the stage ---------------------------------------------------------------------------------------


def run_substances(
    settings: Settings | None = None,
    bootstrap_count: int = 400,
    size: int = 128,
    spp: int = 32,
    train_config: str | SubstanceTrainConfig = "cpu",
    *,
    batch: int = 16,
    train_overrides: dict[str, Any] | None = None,
    progress: Progress | None = None,
    renderer: RendererProtocol | None = None,
    store: BlobStore | None = None,
    exposure: str = "as-is",
) -> dict[str, Any]:
    """The whole substances stage: bootstrap renders -> substance network -> PartSubstance rows."""
    settings = settings or get_settings()
    store = store if store is not None else default_store(settings)
    bootstrap = run_training_renders("bootstrap", bootstrap_count, size, spp, settings, batch=batch,
                                     renderer=renderer, progress=progress, store=store, exposure=exposure)
    return {"bootstrap": bootstrap,
            **train_and_assign(settings, size, train_config, train_overrides, progress, store=store)}


def train_and_assign(settings: Settings, size: int, train_config: str | SubstanceTrainConfig = "cpu",
                     train_overrides: dict[str, Any] | None = None,
                     progress: Progress | None = None, *, store: BlobStore | None = None) -> dict[str, Any]:
    """The network on the bootstrap renders that exist (trained or resumed), then every part's substance."""
    store = store if store is not None else default_store(settings)
    classifier_id, model, info = train_or_resume(settings, train_config, progress=progress, store=store,
                                                 **(train_overrides or {}))
    predict_size = _config_size(settings, classifier_id) or size
    choice = choose_substance_bn_prior(settings, classifier_id, model, predict_size, store=store)
    parts = assign_part_substances(settings, classifier_id, model, predict_size, bn_prior=choice["bn_prior"],
                                   progress=progress, store=store)
    return {"network": info, "bn_prior": choice, "part_substances": parts}


def _config_size(settings: Settings, classifier_id: int) -> int | None:
    with session_scope(settings.resolved_database_url) as session:
        row = session.get(m.Classifier, classifier_id)
        return read_side_of(row.config) if row is not None else None
