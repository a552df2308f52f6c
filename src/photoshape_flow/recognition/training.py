"""Stage "training": the material classifier from the synthetic training renders (section 5.2).

`run_training(config)`:

1. The material list is every enabled material with status ok, ordered by id; its
   `material_set_hash` covers (id, name, substance). The data are the ok, not excluded `Rendering`
   rows of kind "training" that have "beauty" and "material_ids" blobs, split by their `split`
   column ("val" -> validation; when no row is "val", a stable ~10% by key hash is held out).
2. params_hash = sha256(code version, config hash, material-set hash, data hash). An ok material
   classifier with that hash is reused (idempotent re-runs).
3. A row with that hash still "training" (killed) or "failed" resumes from its `checkpoint_blob`:
   the loop restarts at the next epoch with the saved optimizer, log-variances and RNG state.
4. Otherwise a new row (status "training") is written. When the material set grew since the newest
   ok material classifier of the same architecture (its materials a strict subset of the current
   ones), training starts from it: `classify.networks.grow_materials` keeps the trained rows, adds the
   new ones, and only `config.finetune_epochs` are run (`parent_id` records it). `finetune_from`
   forces a parent. A descriptor (`head="descriptor"`) with `finetune_epochs=0` is not trained at
   all: the new materials are read from their renders (step 5's vectors), the row's epoch is 0.
5. Each epoch's checkpoint goes to the blob store, then onto the row (blob first, then row). At the
   end the row gets the slim (inference) checkpoint, holding the weights of the best validation
   epoch when the config has a `select_metric` (else the last), that epoch's Table 4 metrics
   (`metrics.selected_epoch` says which) and status "ok"; the
   metrics are also written as `Evaluation` rows (run = classifier name, stage "training"). A
   descriptor network (`head="descriptor"`) first gets each material's descriptor from the training
   renders through those weights (`classify.descriptor.fit_prototypes`).
"""

from __future__ import annotations

import hashlib
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.backbone import backbone_record
from photoshape_flow.classify.configs import ClassifierConfig, config_hash, get_config
from photoshape_flow.classify.dataset import RegionDataset, RenderItem, find_regions
from photoshape_flow.classify.descriptor import fit_prototypes
from photoshape_flow.classify.networks import build_network, grow_materials
from photoshape_flow.classify.train import history_entry, select_best, train_classifier
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db.base import utcnow
from photoshape_flow.db.models import Classifier, Evaluation, Rendering
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.devices import resolve_device, set_torch_threads
from photoshape_flow.faults import fault_point
from photoshape_flow.hashing import stable_hash
from photoshape_flow.networks.classifier_rows import newest_material_classifier
from photoshape_flow.pipeline.errors import error_line
from photoshape_flow.progress_sink import Progress, no_progress
from photoshape_flow.recognition.material_sets import MaterialSet, material_set
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK

log = logging.getLogger(__name__)

CODE_VERSION = "material-classifier-1"
STATUS_TRAINING = "training"
TRAINING_KINDS: tuple[str, ...] = ("training",)
METRIC_KEYS = ("mtl@1", "mtl@5", "sub@1", "sub-mtl@1")


@dataclass(frozen=True)
class TrainingData:
    train: tuple[RenderItem, ...]
    val: tuple[RenderItem, ...]
    hash: str
    val_source: str  # "split" (rows marked val) | "held-out" (by key hash) | "none"


def _held_out(key: str, fraction: float) -> bool:
    digest = hashlib.sha256(key.encode()).digest()
    return int.from_bytes(digest[:4], "little") / 2**32 < fraction


def training_data(
    session: Session, store: BlobStore, kinds: Sequence[str] = TRAINING_KINDS, val_fraction: float = 0.1
) -> TrainingData:
    """Training and validation renderings as file pairs, plus a hash of exactly what they contain."""
    rows = session.execute(
        sa.select(Rendering.kind, Rendering.key, Rendering.split, Rendering.blobs)
        .where(Rendering.kind.in_(list(kinds)), Rendering.status == STATUS_OK, Rendering.exclude.is_(False))
        .order_by(Rendering.kind, Rendering.key)
    ).all()
    usable = []
    for row in rows:
        blobs = row.blobs or {}
        beauty, ids = blobs.get("beauty"), blobs.get("material_ids")
        if not beauty or not ids:
            log.warning("rendering %s/%s: no beauty or material_ids blob; skipped", row.kind, row.key)
            continue
        if not (store.exists(beauty) and store.exists(ids)):
            log.warning("rendering %s/%s: blob missing from the store; skipped", row.kind, row.key)
            continue
        usable.append((row.kind, row.key, row.split, beauty, ids))
    any_val = any(split == "val" for _, _, split, _, _ in usable)
    train, val, manifest = [], [], []
    for kind, key, split, beauty, ids in usable:
        is_val = split == "val" if any_val else _held_out(f"{kind}/{key}", val_fraction)
        item = RenderItem(store.resolve(beauty), store.resolve(ids), f"{kind}/{key}")
        (val if is_val else train).append(item)
        manifest.append([kind, key, beauty, ids, "val" if is_val else "train"])
    source = "split" if any_val else ("held-out" if val else "none")
    return TrainingData(tuple(train), tuple(val), stable_hash(manifest), source)


def _parent_candidate(
    session: Session, config: ClassifierConfig, materials: MaterialSet, finetune_from: int | None
) -> Classifier | None:
    if finetune_from is not None:
        parent = session.get(Classifier, finetune_from)
        if parent is None or parent.kind != "material" or parent.status != STATUS_OK or not parent.checkpoint_blob:
            raise LookupError(f"classifier {finetune_from}: not an ok material classifier to fine-tune from")
        if parent.architecture != config.architecture:
            raise ValueError(
                f"classifier {finetune_from}: architecture {parent.architecture} differs from {config.architecture}"
            )
        return parent
    newest = newest_material_classifier(session)
    if newest is None or newest.architecture != config.architecture:
        return None
    old = {int(m) for m in (newest.materials or [])[1:]}
    return newest if old and old < set(materials.ids) else None


def _metrics(history: list[dict[str, Any]], selected_epoch: int | None = None, **extra: Any) -> dict[str, Any]:
    """Table 4 metrics of the selected epoch (default: the last), plus totals over the whole run."""
    last = history_entry(history, selected_epoch)
    metrics: dict[str, Any] = {key: last.get(key) for key in METRIC_KEYS}
    metrics["selected_epoch"] = last.get("epoch")
    for key in ("val_material_loss", "val_examples", "train_loss", "log_var_material", "log_var_substance"):
        metrics[key] = last.get(key)
    seconds = [h.get("train_seconds") or 0.0 for h in history]
    images = [h.get("images") or 0 for h in history]
    metrics["train_seconds"] = sum(seconds)
    metrics["images_per_s"] = sum(images) / sum(seconds) if sum(seconds) > 0 else None
    metrics.update(extra)
    metrics["history"] = history
    return metrics


def _drop_superseded(store: BlobStore, old: str | None, new: str) -> None:
    """Delete this classifier's previous resume checkpoint once the row points at a newer one.

    Full checkpoints (weights + optimizer state) are large (~135 MB for ResNet-18 with Adam) and only
    the newest is ever resumed from, so waiting for `gc` would pile one up per epoch.
    """
    if old and old != new:
        store.delete(old)


def _with_prototypes(checkpoint: dict[str, Any], renders: RegionDataset, cfg: ClassifierConfig,
                     device: Any) -> dict[str, Any]:
    """`checkpoint` with the descriptor's prototypes set from `renders` (read without augmentation)."""
    model = ckpt.build_model(checkpoint).to(device)
    parts = fit_prototypes(model, renders, seed=cfg.seed, batch_size=cfg.eval_batch_size, device=device)
    log.info("material descriptors from %d rendered parts", parts)
    return {**checkpoint, "model": {k: v.detach().cpu() for k, v in model.state_dict().items()}}


def run_training(
    config: str | ClassifierConfig = "cpu",
    name: str | None = None,
    settings: Settings | None = None,
    finetune_from: int | None = None,
    *,
    overrides: dict[str, Any] | None = None,
    kinds: Sequence[str] = TRAINING_KINDS,
    progress: Progress | None = None,
    network_kind: str = "material",
    store: BlobStore | None = None,
) -> int:
    """Train (or reuse, or resume) the material classifier; returns its `Classifier` id.

    ``network_kind="substance"``: the same network trained as the substances stage's recogniser (on
    the bootstrap round, its substance head read per part): its row has kind "substance", so it is
    never taken for the material classifier, and it never fine-tunes from one.
    """
    import torch

    settings = settings or get_settings()
    cfg = config if isinstance(config, ClassifierConfig) else get_config(config, **(overrides or {}))
    cfg.check()
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    set_torch_threads(settings.torch_threads)

    with session_scope(url) as session:
        materials = material_set(session)
        data = training_data(session, store, kinds, cfg.val_fraction)
    if not materials.ids:
        raise ValueError("no enabled materials with status ok: nothing for the classifier to predict")
    backbone = backbone_record(cfg)
    params_hash = stable_hash([CODE_VERSION, config_hash(cfg), materials.hash, data.hash, *backbone.values()])

    with session_scope(url) as session:
        rows = session.scalars(
            sa.select(Classifier)
            .where(Classifier.kind == network_kind, Classifier.params_hash == params_hash)
            .order_by(Classifier.id.desc())
        ).all()
        done = next((r for r in rows if r.status == STATUS_OK and r.checkpoint_blob), None)
        if done is not None:
            log.info("material classifier %s (id %d) is up to date; reused", done.name, done.id)
            return done.id
        unfinished = next((r for r in rows if r.status in (STATUS_TRAINING, STATUS_FAILED)), None)
        resume_ref = unfinished.checkpoint_blob if unfinished is not None else None
        if unfinished is not None:
            name, parent_id = unfinished.name, unfinished.parent_id
        else:
            name = name or f"{network_kind}-{cfg.name}-{params_hash[:12]}"
            taken = session.scalars(sa.select(Classifier).where(Classifier.name == name)).first()
            if taken is not None and taken.status == STATUS_OK:
                raise ValueError(f"classifier name {name!r} is taken by classifier {taken.id} trained on other inputs")
            parent = _parent_candidate(session, cfg, materials, finetune_from) if network_kind == "material" else None
            parent_id = parent.id if parent is not None else None
        parent_row = session.get(Classifier, parent_id) if parent_id is not None else None
        parent_ref = parent_row.checkpoint_blob if parent_row is not None else None
        epochs = cfg.finetune_epochs if parent_id is not None else cfg.epochs
        row_values: dict[str, Any] = {
            "name": name,
            "kind": network_kind,
            "architecture": cfg.architecture,
            "config": {**cfg.to_dict(), **backbone, "data_hash": data.hash, "epochs_planned": epochs,
                       "finetune": parent_id is not None, "kinds": list(kinds)},
            "material_set_hash": materials.hash,
            "materials": [0, *materials.ids],
            "parent_id": parent_id,
            "status": STATUS_TRAINING,
            "error": None,
            "params_hash": params_hash,
        }
        if resume_ref is None:
            row_values.update(checkpoint_blob=None, epoch=0, metrics={})
        (classifier_id,) = upsert(session, Classifier, row_values, key=["name"])

    device = resolve_device(settings.device)
    log.info(
        "training material classifier %s (id %d): %d materials, %d/%d train/val renderings, %s, %s%s",
        name, classifier_id, len(materials.ids), len(data.train), len(data.val), cfg.architecture, device,
        f", fine-tuning classifier {parent_id}" if parent_id else "",
    )
    try:
        substance_of = materials.substance_of
        train_examples = find_regions(data.train, materials.ids, substance_of,
                                      min_fraction=cfg.min_region_fraction, background_every=cfg.background_every)
        val_examples = find_regions(data.val, materials.ids, substance_of, min_fraction=cfg.min_region_fraction)
        if len(train_examples) < 2:
            raise ValueError(
                f"only {len(train_examples)} training regions in {len(data.train)} renderings of kind "
                f"{'/'.join(kinds)}; run the training-renders stage first"
            )
        train_set = RegionDataset(data.train, train_examples, cfg.image_size, cfg.augment, seed=cfg.seed,
                                  frame=cfg.frame_object)
        val_set = (RegionDataset(data.val, val_examples, cfg.image_size, frame=cfg.frame_object)
                   if val_examples else None)

        resume = ckpt.load(store.read_bytes(resume_ref)) if resume_ref else None
        if resume is not None:
            if list(resume["materials"]) != list(materials.ids):
                raise ValueError(f"classifier {classifier_id}: checkpoint material list differs from the current one")
            model = ckpt.build_model(resume)
            log.info("resuming classifier %d after epoch %d", classifier_id, resume["epoch"])
        elif parent_ref is not None:
            parent_ckpt = ckpt.load(store.read_bytes(parent_ref))
            model = ckpt.build_model(parent_ckpt)
            grow_materials(model, parent_ckpt["materials"], materials.ids, substance_of,
                           generator=torch.Generator().manual_seed(cfg.seed))
        else:
            model = build_network(cfg, len(materials.ids), seed=cfg.seed)

        current = {"ref": resume_ref}
        report = progress or no_progress
        report("training epochs", int(resume["epoch"]) if resume else 0, epochs)

        def save(checkpoint: dict[str, Any]) -> None:
            ref = store.put_bytes(ckpt.to_bytes(checkpoint), "pt")
            with session_scope(url) as session:
                session.execute(
                    sa.update(Classifier).where(Classifier.id == classifier_id).values(
                        checkpoint_blob=ref, epoch=int(checkpoint["epoch"]),
                        metrics=_metrics(checkpoint["history"]), updated_at=utcnow(),
                    )
                )
            _drop_superseded(store, current["ref"], ref)
            current["ref"] = ref
            fault_point("training-checkpoint-saved")
            report("training epochs", int(checkpoint["epoch"]), epochs)

        started = time.perf_counter()
        result = train_classifier(
            model, train_set, val_set, cfg, materials=materials.ids, material_substances=materials.substances,
            epochs=epochs, device=device, resume=resume, save=save,
            extra={"classifier_id": classifier_id, "params_hash": params_hash},
        )
        final = result.checkpoint
        if final is None:  # already complete before this call (resumed at the last epoch)
            final = resume
        if final is None and epochs == 0:  # a descriptor's grown list, `finetune_epochs=0`: vectors only
            final = ckpt.make_checkpoint(model, materials=materials.ids, material_substances=materials.substances,
                                         image_size=cfg.image_size, config=cfg.to_dict(), epoch=0, history=[])
        assert final is not None
        final = select_best(ckpt.slim(final))  # the best validation epoch's weights when the config selects
        if cfg.head == "descriptor":  # each material's descriptor from its renders, with the selected weights
            final = _with_prototypes(final, RegionDataset(data.train, train_examples, cfg.image_size,
                                                          frame=cfg.frame_object), cfg, device)
        ref = store.put_bytes(ckpt.to_bytes(final), "pt")
        metrics = _metrics(
            result.history,
            final["selected_epoch"],
            epochs=result.epoch,
            train_examples=len(train_examples),
            val_examples=len(val_examples),
            train_renderings=len(data.train),
            val_renderings=len(data.val),
            val_source=data.val_source,
            device=str(device),
            finetuned_from=parent_id,
            wall_seconds=time.perf_counter() - started,
        )
    except BaseException as exc:
        with session_scope(url) as session:
            session.execute(
                sa.update(Classifier).where(Classifier.id == classifier_id).values(
                    status=STATUS_FAILED, error=error_line(exc),
                    updated_at=utcnow(),
                )
            )
        raise

    with session_scope(url) as session:
        session.execute(
            sa.update(Classifier).where(Classifier.id == classifier_id).values(
                status=STATUS_OK, error=None, checkpoint_blob=ref, epoch=result.epoch, metrics=metrics,
                updated_at=utcnow(),
            )
        )
    _drop_superseded(store, current["ref"], ref)
    stage = "training" if network_kind == "material" else "substances"
    with session_scope(url) as session:
        evaluations = [
            {"run": name, "stage": stage, "method": "classifier", "metric": key, "value": metrics[key],
             "count": len(val_examples), "params": {"classifier_id": classifier_id, "config": cfg.name}}
            for key in METRIC_KEYS
            if metrics.get(key) is not None
        ]
        if evaluations:
            upsert(session, Evaluation, evaluations, key=["run", "stage", "method", "metric"])
    log.info("material classifier %s (id %d) done: %s", name, classifier_id,
             ", ".join(f"{k} {metrics[k]:.3f}" for k in METRIC_KEYS if metrics.get(k) is not None))
    return classifier_id
