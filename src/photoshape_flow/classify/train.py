"""Training loop of the material classifier (section 5.2), resumable epoch by epoch.

SGD as in the paper (fixed learning rate 1e-4, momentum 0.9, weight decay 1e-4) or Adam, with the
log-variances of the multitask loss in their own parameter group without weight decay. After every
epoch the loop evaluates the validation set with the paper's Table 4 metrics and hands a full
checkpoint (model, optimizer, log-variances, epoch, RNG state, material list, history) to a `save`
callback; the pipeline stores it in the blob store. Passing that checkpoint back as `resume`
continues exactly where it stopped: the shuffling order and every augmentation are drawn from
generators seeded by (config seed, epoch, example), not from global state, so a resumed run takes
the same steps as an uninterrupted one.

With ``config.lr_schedule == "cosine"`` the learning rate follows a cosine from ``lr`` down to
``lr * lr_floor`` over all steps of the run, set before every step from the global step index (no
scheduler state, so resuming needs nothing extra). With ``config.select_metric`` the loop also keeps
the weights of the epoch with the best validation value of that metric (in the checkpoint, so a
resumed run still knows them); `select_best` turns a final checkpoint into one holding those weights.

Table 4 metrics (background excluded from the rankings: a region is known to hold a material):
``mtl@1`` / ``mtl@5`` top-1 / top-5 material precision, ``sub@1`` top-1 of the substance head,
``sub-mtl@1`` top-1 of the substance implied by summing material probabilities per substance.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch.utils.data import DataLoader

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.classify.dataset import RegionDataset, example_seed, substance_label
from photoshape_flow.classify.loss import MultitaskLoss
from photoshape_flow.classify.networks import MaterialNetwork
from photoshape_flow.classify.resnet import NUM_SUBSTANCE_OUTPUTS

log = logging.getLogger(__name__)

METRIC_KEYS = ("mtl@1", "mtl@5", "sub@1", "sub-mtl@1")


def make_loss(config: ClassifierConfig) -> MultitaskLoss:
    return MultitaskLoss(
        mode=config.loss_mode,  # type: ignore[arg-type]
        material_weight=config.material_weight,
        substance_weight=config.substance_weight,
        init_log_var_material=config.init_log_var_material,
        init_log_var_substance=config.init_log_var_substance,
    )


def make_optimizer(model: torch.nn.Module, loss: MultitaskLoss, config: ClassifierConfig) -> torch.optim.Optimizer:
    """The optimizer with groups for the network weights (decayed) and the log-variances (never decayed).

    A network on a pretrained backbone gives its own groups (new heads at the full step, fine-tuned
    blocks at ``backbone_lr_scale`` of it: `lr_scale` in the group); frozen weights are left out.
    """
    split = getattr(model, "parameter_groups", None)
    groups: list[dict[str, Any]] = (
        split(config.weight_decay, config.backbone_lr_scale) if callable(split)
        else [{"params": [p for p in model.parameters() if p.requires_grad], "weight_decay": config.weight_decay}]
    )
    learned = loss.learned_parameters()
    if learned:
        groups.append({"params": learned, "weight_decay": 0.0})
    if config.optimizer == "sgd":
        return torch.optim.SGD(groups, lr=config.lr, momentum=config.momentum)
    if config.optimizer == "adam":
        # AdamW: decoupled decay, so weight_decay means the same thing as in SGD's group split
        return torch.optim.AdamW(groups, lr=config.lr)
    raise ValueError(f"unknown optimizer {config.optimizer!r}; expected 'sgd' or 'adam'")


def material_substance_index(material_substances: Sequence[str]) -> torch.Tensor:
    """Substance label (SUBSTANCE_LABELS index) per material-head output, background first."""
    return torch.tensor([0, *(substance_label(s) for s in material_substances)], dtype=torch.long)


def learning_rate(config: ClassifierConfig, step: int, total_steps: int) -> float:
    """The learning rate of global step `step` (0-based) of a run of `total_steps` steps."""
    if config.lr_schedule == "constant":
        return config.lr
    if config.lr_schedule != "cosine":
        raise ValueError(f"unknown lr_schedule {config.lr_schedule!r}; expected 'constant' or 'cosine'")
    progress = min(max(step, 0) / max(total_steps - 1, 1), 1.0)
    floor = config.lr * config.lr_floor
    return floor + 0.5 * (config.lr - floor) * (1.0 + math.cos(math.pi * progress))


def _better(value: Any, best: Any) -> bool:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return best is None or float(value) > float(best)


def select_best(checkpoint: dict[str, Any]) -> dict[str, Any]:
    """The checkpoint with its weights replaced by the best validation epoch's (when it kept one).

    ``selected_epoch`` records the epoch whose weights the result holds; ``epoch`` stays the number
    of epochs trained.
    """
    best = checkpoint.get("best")
    out = {k: v for k, v in checkpoint.items() if k != "best"}
    if best is None:
        out["selected_epoch"] = int(checkpoint["epoch"])
        return out
    out["model"] = best["model"]
    out["selected_epoch"] = int(best["epoch"])
    return out


def worker_context(num_workers: int, device: torch.device | str) -> str | None:
    """How data-loader workers start: "forkserver" once the process drives a GPU, else the default.

    Forking a process whose CUDA runtime is running copies its threads' locks half-held, and a worker
    can deadlock (Python warns at every fork); a fork server starts workers from a clean process. On
    the CPU the default fork is kept: it is faster to start and nothing is at risk.
    """
    return "forkserver" if num_workers > 0 and torch.device(device).type == "cuda" else None


@torch.inference_mode()
def evaluate(
    model: MaterialNetwork,
    dataset: RegionDataset,
    material_substances: Sequence[str],
    *,
    batch_size: int = 64,
    device: torch.device | str = "cpu",
    num_workers: int = 0,
) -> dict[str, float | int | None]:
    """Table 4 metrics over the non-background examples of `dataset` (None when it is empty)."""
    device = torch.device(device)
    was_training = model.training
    model.eval()
    index = material_substance_index(material_substances).to(device)
    correct = dict.fromkeys(METRIC_KEYS, 0)
    total, loss_sum = 0, 0.0
    loader = DataLoader(dataset, batch_size=batch_size, shuffle=False, num_workers=num_workers,
                        multiprocessing_context=worker_context(num_workers, device))
    for x, y_mat, y_sub in loader:
        keep = y_mat > 0
        if not bool(keep.any()):
            continue
        x, y_mat, y_sub = x[keep].to(device), y_mat[keep].to(device), y_sub[keep].to(device)
        mat_logits, sub_logits = model(x)
        loss_sum += float(torch.nn.functional.cross_entropy(mat_logits, y_mat, reduction="sum"))
        probs = mat_logits.softmax(1)
        ranked = probs[:, 1:].argsort(1, descending=True) + 1
        correct["mtl@1"] += int((ranked[:, 0] == y_mat).sum())
        correct["mtl@5"] += int((ranked[:, :5] == y_mat[:, None]).any(1).sum())
        correct["sub@1"] += int((sub_logits[:, 1:].argmax(1) + 1 == y_sub).sum())
        implied = torch.zeros(len(x), NUM_SUBSTANCE_OUTPUTS, device=device).index_add_(1, index, probs)
        correct["sub-mtl@1"] += int((implied[:, 1:].argmax(1) + 1 == y_sub).sum())
        total += len(x)
    model.train(was_training)
    metrics: dict[str, float | int | None] = {
        key: (correct[key] / total if total else None) for key in METRIC_KEYS
    }
    metrics["val_material_loss"] = loss_sum / total if total else None
    metrics["val_examples"] = total
    return metrics


@dataclass
class TrainResult:
    model: MaterialNetwork
    loss: MultitaskLoss
    epoch: int
    history: list[dict[str, Any]] = field(default_factory=list)
    checkpoint: dict[str, Any] | None = None
    best_epoch: int | None = None  # the epoch `select_best` picks (None: no validation metric kept one)

    @property
    def selected_epoch(self) -> int:
        return self.best_epoch if self.best_epoch is not None else self.epoch

    @property
    def metrics(self) -> dict[str, Any]:
        """The history entry of the selected epoch (the best one when a metric selects, else the last)."""
        return dict(history_entry(self.history, self.selected_epoch))


def history_entry(history: Sequence[dict[str, Any]], epoch: int | None = None) -> dict[str, Any]:
    """The history entry of `epoch` (the last entry when `epoch` is None or absent; {} when empty)."""
    if epoch is not None:
        for entry in history:
            if entry.get("epoch") == epoch:
                return entry
    return history[-1] if history else {}


def train_classifier(
    model: MaterialNetwork,
    train_set: RegionDataset,
    val_set: RegionDataset | None,
    config: ClassifierConfig,
    *,
    materials: Sequence[int],
    material_substances: Sequence[str],
    epochs: int | None = None,
    device: torch.device | str = "cpu",
    resume: dict[str, Any] | None = None,
    save: Callable[[dict[str, Any]], None] | None = None,
    stop_after_epochs: int | None = None,
    extra: dict[str, Any] | None = None,
) -> TrainResult:
    """Train `model` for `epochs` (default `config.epochs`), resuming from a checkpoint if given.

    `save(checkpoint)` is called after each epoch with a full checkpoint; `stop_after_epochs` ends
    the call early after that many epochs of this call (simulates an interruption in tests).
    """
    device = torch.device(device)
    total_epochs = config.epochs if epochs is None else int(epochs)
    if len(train_set) < 2:
        raise ValueError(f"need at least 2 training examples, got {len(train_set)}")
    loss_fn = make_loss(config)
    history: list[dict[str, Any]] = []
    start_epoch = 0
    best: dict[str, Any] | None = None  # {"epoch", "metric", "value", "model"}: the selected weights
    if resume is not None:
        model.load_state_dict(resume["model"])
        if "loss" in resume:
            loss_fn.load_state_dict(resume["loss"])
        start_epoch = int(resume["epoch"])
        history = list(resume.get("history") or [])
        best = resume.get("best")
    model.to(device)
    loss_fn.to(device)
    if config.channels_last:
        model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    optimizer = make_optimizer(model, loss_fn, config)
    if resume is not None and "optimizer" in resume:
        optimizer.load_state_dict(resume["optimizer"])
    if resume is not None and "rng" in resume:
        torch.set_rng_state(resume["rng"]["torch"])

    config_dict = config.to_dict()
    batch_size = min(config.batch_size, len(train_set))
    last: dict[str, Any] | None = None
    epochs_run = 0
    for epoch in range(start_epoch, total_epochs):
        if stop_after_epochs is not None and epochs_run >= stop_after_epochs:
            break
        started = time.perf_counter()
        train_set.set_epoch(epoch)
        # the network's own random draws (dropout) restart from (seed, epoch) on every device, so a run
        # resumed after this epoch's start draws what an uninterrupted one does, on cuda too
        torch.manual_seed(example_seed(config.seed, epoch, 1 << 41))
        order = torch.randperm(len(train_set), generator=torch.Generator().manual_seed(
            example_seed(config.seed, epoch, 1 << 40)))
        num_batches = len(train_set) // batch_size
        if config.max_steps_per_epoch:
            num_batches = min(num_batches, config.max_steps_per_epoch)
        total_steps = total_epochs * num_batches
        sampler = order[: num_batches * batch_size].tolist()
        loader = DataLoader(train_set, batch_size=batch_size, sampler=sampler, num_workers=config.num_workers,
                            pin_memory=device.type == "cuda", persistent_workers=False,
                            multiprocessing_context=worker_context(config.num_workers, device))
        model.train()
        sums = {"loss": 0.0, "material": 0.0, "substance": 0.0}
        images = 0
        for step, (x, y_mat, y_sub) in enumerate(loader):
            lr = learning_rate(config, epoch * num_batches + step, total_steps)
            for group in optimizer.param_groups:  # the log-variances' group follows the same schedule
                group["lr"] = lr * group.get("lr_scale", 1.0)
            x = x.to(device, non_blocking=True)
            if config.channels_last:
                x = x.contiguous(memory_format=torch.channels_last)
            y_mat, y_sub = y_mat.to(device), y_sub.to(device)
            mat_logits, sub_logits = model(x)
            out = loss_fn(mat_logits, sub_logits, y_mat, y_sub)
            if not torch.isfinite(out.total):
                raise FloatingPointError(f"epoch {epoch + 1}: non-finite loss {float(out.total)}")
            optimizer.zero_grad(set_to_none=True)
            out.total.backward()
            optimizer.step()
            n = len(x)
            sums["loss"] += float(out.total.detach()) * n
            sums["material"] += float(out.material) * n
            sums["substance"] += float(out.substance) * n
            images += n
        train_seconds = time.perf_counter() - started
        entry: dict[str, Any] = {
            "epoch": epoch + 1,
            "steps": num_batches,
            "images": images,
            "train_loss": sums["loss"] / max(images, 1),
            "train_material_loss": sums["material"] / max(images, 1),
            "train_substance_loss": sums["substance"] / max(images, 1),
            "log_var_material": float(loss_fn.log_var_material.detach()),
            "log_var_substance": float(loss_fn.log_var_substance.detach()),
            "lr": optimizer.param_groups[0]["lr"],
            "train_seconds": train_seconds,
            "images_per_s": images / train_seconds if train_seconds > 0 else None,
        }
        if val_set is not None and len(val_set):
            entry.update(evaluate(model, val_set, material_substances, batch_size=config.eval_batch_size,
                                  device=device, num_workers=config.num_workers))
            if not config.substance_weight:  # Table 4 "sub = N": the substance head is untrained
                entry["sub@1"] = None
        entry["seconds"] = time.perf_counter() - started
        history.append(entry)
        log.info("epoch %d/%d: %s", epoch + 1, total_epochs, _summary(entry))
        last = ckpt.make_checkpoint(
            model, materials=materials, material_substances=material_substances, image_size=config.image_size,
            config=config_dict, epoch=epoch + 1, history=history, optimizer=optimizer, loss=loss_fn, extra=extra,
        )
        value = entry.get(config.select_metric) if config.select_metric else None
        if _better(value, best["value"] if best is not None else None):
            # the checkpoint's own copy of the weights (torch.save stores shared tensors once)
            best = {"epoch": epoch + 1, "metric": config.select_metric, "value": float(value), "model": last["model"]}
        if best is not None:
            last["best"] = best
        if save is not None:
            save(last)
        epochs_run += 1
    final_epoch = start_epoch + epochs_run
    return TrainResult(model=model, loss=loss_fn, epoch=final_epoch, history=history, checkpoint=last,
                       best_epoch=int(best["epoch"]) if best is not None else None)


def _summary(entry: dict[str, Any]) -> str:
    parts = [f"loss {entry['train_loss']:.3f}"]
    for key in METRIC_KEYS:
        value = entry.get(key)
        if value is not None and not (isinstance(value, float) and math.isnan(value)):
            parts.append(f"{key} {value:.3f}")
    parts.append(f"{entry.get('images_per_s') or 0:.1f} img/s")
    return ", ".join(parts)
