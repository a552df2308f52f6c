"""Training and inference of the substance segmentation network (pure: arrays in, checkpoints out).

Data: bootstrap renders (sRGB on white) with their per-pixel `substance_ids` labels; optionally each
first cut to the square around its object (``frame_object``), as exemplars are cropped. Augmentation
per sample: an optional random Gaussian blur (sigma ~ U(0, ``blur``), against the renders' sampling
noise), random square crop covering `crop_scale` of the area, resized to `size`; horizontal flip;
colour jitter (brightness, contrast, saturation). Framing and blur are off in every preset: they
measured worse on the medium demo (docs/decisions.md, D4).
Loss: per-pixel cross-entropy with class weights ~ frequency^-1/2 (the white background dominates
the pixels); with ``part_balance`` p > 0 each part's pixels also weigh (part area)^-p, from the
renders' part maps (`part_weights`). AdamW with a cosine learning-rate
schedule computed from the global iteration, so a resumed run follows the same schedule.

Resumability: `train_substance_net` calls `on_epoch(checkpoint, metrics)` after every epoch; the
checkpoint dict (model, optimiser, epoch, config, metrics, history) round-trips through
`checkpoint_to_bytes` / `checkpoint_from_bytes`. Passing it back as `checkpoint=` continues with the
next epoch; the random streams are seeded per (seed, epoch), so an interrupted and resumed run draws
the same batches as an uninterrupted one. The pipeline stores checkpoints in the blob store and the
Classifier row; this module knows nothing of either.

Configurations (`SubstanceTrainConfig` and its presets) live in `classify/substance_configs.py`, so
profiles can nest them without importing torch.
"""

from __future__ import annotations

import io
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from photoshape_flow.classify.bn_adapt import adapted_batchnorm
from photoshape_flow.classify.dataset import frame_object
from photoshape_flow.classify.substance_configs import SubstanceTrainConfig
from photoshape_flow.classify.substance_net import NUM_CLASSES, SubstanceNet
from photoshape_flow.vocab import SUBSTANCE_LABELS

log = logging.getLogger(__name__)


@dataclass
class SubstanceData:
    """Images (H, W, 3) uint8 and label maps (H, W) uint8 (SUBSTANCE_LABELS indices); sizes may vary.

    `parts`: optional part-index maps (H, W) (0 = background), needed only when the loss balances
    parts (`SubstanceTrainConfig.part_balance`).
    """

    images: list[np.ndarray]
    labels: list[np.ndarray]
    keys: list[str] = field(default_factory=list)
    parts: list[np.ndarray] | None = None

    def __post_init__(self) -> None:
        if len(self.images) != len(self.labels):
            raise ValueError("images and labels differ in number")
        for image, label in zip(self.images, self.labels, strict=True):
            if image.shape[:2] != label.shape:
                raise ValueError(f"image {image.shape} and label map {label.shape} differ in size")
        if self.parts is not None and [p.shape for p in self.parts] != [lb.shape for lb in self.labels]:
            raise ValueError("part maps and label maps differ in number or size")

    def __len__(self) -> int:
        return len(self.images)

    def framed(self) -> SubstanceData:
        """Each image and label map cropped to the square around its object (`frame_object`)."""
        maps = self.label_stacks()
        pairs = [frame_object(image, stack) for image, stack in zip(self.images, maps, strict=True)]
        labels = [p[1] if p[1].ndim == 2 else p[1][..., 0].astype(np.uint8) for p in pairs]
        parts = None if self.parts is None else [p[1][..., 1] for p in pairs]
        return SubstanceData([p[0] for p in pairs], labels, list(self.keys), parts)

    def label_stacks(self) -> list[np.ndarray]:
        """The label maps, each with its part map as a second channel (uint16) when parts are known."""
        if self.parts is None:
            return list(self.labels)
        return [np.dstack([label, part]).astype(np.uint16) for label, part in zip(self.labels, self.parts, strict=True)]


# -- augmentation -----------------------------------------------------------------------------------


def _resize(array: np.ndarray, size: int, nearest: bool) -> np.ndarray:
    import cv2

    if array.shape[0] == size and array.shape[1] == size:
        return array
    shrink = array.shape[0] > size
    interp = cv2.INTER_NEAREST if nearest else (cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return cv2.resize(array, (size, size), interpolation=interp)


def augment(
    image: np.ndarray, label: np.ndarray, config: SubstanceTrainConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Random blur, square crop + resize, flip, colour jitter; float32 (H, W, 3) in [0, 1] and labels.

    `label` is (H, W) or (H, W, C) (e.g. substances and parts stacked): every channel follows the crop.
    """
    if config.blur > 0:
        import cv2

        sigma = float(rng.uniform(0.0, config.blur))
        if sigma > 0.05:
            image = cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    h, w = label.shape[:2]
    side_max = min(h, w)
    area = rng.uniform(*config.crop_scale)
    side = int(np.clip(round(math.sqrt(area) * side_max), 4, side_max))
    y0 = int(rng.integers(0, h - side + 1))
    x0 = int(rng.integers(0, w - side + 1))
    img = _resize(image[y0 : y0 + side, x0 : x0 + side], config.size, nearest=False)
    lab = _resize(label[y0 : y0 + side, x0 : x0 + side], config.size, nearest=True)
    if config.flip and rng.random() < 0.5:
        img, lab = img[:, ::-1], lab[:, ::-1]
    out = img.astype(np.float32) / 255.0
    j = config.jitter
    if j > 0:
        out = out * rng.uniform(1 - j, 1 + j)
        mean = out.mean()
        out = (out - mean) * rng.uniform(1 - j, 1 + j) + mean
        grey = out.mean(axis=2, keepdims=True)
        out = grey + (out - grey) * rng.uniform(1 - j, 1 + j)
    return np.clip(out, 0.0, 1.0), np.ascontiguousarray(lab)


_SLIVER_FRACTION_INVERSE = 1024


def part_weights(parts: np.ndarray, power: float) -> np.ndarray:
    """Per-pixel loss weights (H, W) float32 that let small parts count: each part's pixels weigh
    (part area)^-power, scaled so that the foreground's mean weight is 1; background pixels weigh 1.

    With power 1 every visible part carries the same total weight, whatever its size; 0 is the plain
    per-pixel loss. Why: the per-pixel loss lets a chair's seat outvote its legs by 50:1, yet the
    part-level vote reads each leg on its own, and small parts (legs, frames, handles) carry most of
    the metal. Areas count as at least 1/1024 of the image (16 pixels at 128 px): a sliver a crop
    leaves of a part at its edge is not a part the vote reads, and must not take the loss over.
    """
    parts = np.asarray(parts)
    weights = np.ones(parts.shape, np.float32)
    foreground = parts > 0
    if power <= 0 or not foreground.any():
        return weights
    _, inverse, counts = np.unique(parts[foreground], return_inverse=True, return_counts=True)
    areas = np.maximum(counts[inverse].astype(np.float64), parts.size / _SLIVER_FRACTION_INVERSE)
    raw = areas ** -float(power)
    weights[foreground] = (raw / raw.mean()).astype(np.float32)
    return weights


def _to_tensor(images: Sequence[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous().float()


# -- checkpoints ------------------------------------------------------------------------------------


def checkpoint_to_bytes(checkpoint: dict[str, Any]) -> bytes:
    buffer = io.BytesIO()
    torch.save(checkpoint, buffer)
    return buffer.getvalue()


def checkpoint_from_bytes(data: bytes) -> dict[str, Any]:
    return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)


def load_model(checkpoint: dict[str, Any], device: str = "cpu") -> SubstanceNet:
    """The network of a checkpoint, in eval mode on `device`."""
    config = SubstanceTrainConfig.from_dict(checkpoint["config"])
    model = SubstanceNet(width=config.width)
    model.load_state_dict(checkpoint["model"])
    return model.to(device).eval()


# -- metrics ----------------------------------------------------------------------------------------


def confusion_matrix(pred: np.ndarray, target: np.ndarray, num_classes: int = NUM_CLASSES) -> np.ndarray:
    index = target.astype(np.int64).ravel() * num_classes + pred.astype(np.int64).ravel()
    return np.bincount(index, minlength=num_classes * num_classes).reshape(num_classes, num_classes)


def metrics_from_confusion(conf: np.ndarray) -> dict[str, Any]:
    """Pixel accuracy (all and foreground), per-class IoU (None where a class is absent), mean IoU."""
    conf = conf.astype(np.float64)
    total = conf.sum()
    tp = np.diag(conf)
    iou: dict[str, float | None] = {}
    for k, name in enumerate(SUBSTANCE_LABELS):
        union = conf[k, :].sum() + conf[:, k].sum() - tp[k]
        iou[name] = None if union == 0 else float(tp[k] / union)
    defined = [v for v in iou.values() if v is not None]
    fg_total = conf[1:, :].sum()
    return {
        "pixel_accuracy": float(tp.sum() / total) if total else None,
        "foreground_accuracy": float(tp[1:].sum() / fg_total) if fg_total else None,
        "iou": iou,
        "mean_iou": float(np.mean(defined)) if defined else None,
        "pixels": int(total),
    }


@torch.inference_mode()
def evaluate(model: SubstanceNet, data: SubstanceData, size: int, batch_size: int = 16) -> dict[str, Any]:
    """Metrics with whole images resized to size x size (the read side), labels nearest."""
    device = next(model.parameters()).device
    was_training = model.training
    model.eval()
    conf = np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64)
    for start in range(0, len(data), batch_size):
        imgs = [_resize(im, size, False).astype(np.float32) / 255.0 for im in data.images[start : start + batch_size]]
        labs = [_resize(lb, size, True) for lb in data.labels[start : start + batch_size]]
        pred = model(_to_tensor(imgs).to(device)).argmax(dim=1).cpu().numpy()
        conf += confusion_matrix(pred, np.stack(labs))
    model.train(was_training)
    result = metrics_from_confusion(conf)
    result["images"] = len(data)
    return result


# -- training ---------------------------------------------------------------------------------------


def class_weights(data: SubstanceData) -> np.ndarray:
    counts = np.zeros(NUM_CLASSES, np.float64)
    for label in data.labels:
        counts += np.bincount(label.ravel(), minlength=NUM_CLASSES)[:NUM_CLASSES]
    freq = counts / max(counts.sum(), 1.0)
    weights = np.where(counts > 0, (freq + 1e-6) ** -0.5, 0.0)
    present = weights > 0
    if present.any():
        weights[present] /= (weights[present] * freq[present]).sum() / freq[present].sum()
    weights[~present] = 1.0
    return weights.astype(np.float32)


@dataclass
class TrainResult:
    model: SubstanceNet
    checkpoint: dict[str, Any]
    epochs_run: list[int]
    history: list[dict[str, Any]]


def _lr_at(config: SubstanceTrainConfig, iteration: int, total: int) -> float:
    progress = min(1.0, iteration / max(1, total))
    floor = config.min_lr_fraction
    return config.lr * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress)))


def train_substance_net(
    train: SubstanceData,
    val: SubstanceData | None,
    config: SubstanceTrainConfig,
    *,
    checkpoint: dict[str, Any] | None = None,
    on_epoch: Callable[[dict[str, Any], dict[str, Any]], None] | None = None,
) -> TrainResult:
    """Train (or resume from `checkpoint`) up to `config.epochs`; returns the final model and checkpoint.

    Metrics after each epoch are on `val` (the validation split, by shapes and envmaps) when given,
    else on `train` (flagged ``"split": "train"``).
    """
    if len(train) == 0:
        raise ValueError("no training images for the substance network")
    if config.frame_object:
        train = train.framed()
        val = val.framed() if val is not None else None
    device = torch.device(config.device)
    torch.manual_seed(config.seed)
    model = SubstanceNet(width=config.width).to(device)
    optimizer = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    start_epoch = 1
    history: list[dict[str, Any]] = []
    weights = class_weights(train) if config.class_balance else np.ones(NUM_CLASSES, np.float32)
    if checkpoint is not None:
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        start_epoch = int(checkpoint["epoch"]) + 1
        history = list(checkpoint.get("history", []))
        weights = np.asarray(checkpoint.get("class_weights", weights), np.float32)
    weight_t = torch.from_numpy(weights).to(device)
    balance = float(config.part_balance)
    if balance > 0 and train.parts is None:
        raise ValueError("part_balance needs the training renders' part maps")
    stacks = train.label_stacks() if balance > 0 else train.labels
    iters = config.iters_per_epoch or max(1, math.ceil(len(train) / config.batch_size))
    total_iters = iters * config.epochs
    epochs_run: list[int] = []
    last = checkpoint
    for epoch in range(start_epoch, config.epochs + 1):
        model.train()
        rng = np.random.default_rng([config.seed, epoch])
        torch.manual_seed(config.seed * 100_003 + epoch)
        order = rng.permutation(len(train))
        losses: list[float] = []
        started = time.perf_counter()
        seen = 0
        for it in range(iters):
            idx = [int(order[(it * config.batch_size + k) % len(order)]) for k in range(config.batch_size)]
            pairs = [augment(train.images[i], stacks[i], config, rng) for i in idx]
            x = _to_tensor([p[0] for p in pairs]).to(device)
            maps = np.stack([p[1] for p in pairs]).astype(np.int64)
            y = torch.from_numpy(maps[..., 0] if balance > 0 else maps).to(device)
            for group in optimizer.param_groups:
                group["lr"] = _lr_at(config, (epoch - 1) * iters + it, total_iters)
            if balance > 0:
                pixel = torch.from_numpy(np.stack([part_weights(m[..., 1], balance) for m in maps])).to(device)
                pixel = pixel * weight_t[y]  # the weighted mean F.cross_entropy takes, per pixel
                per_pixel = F.cross_entropy(model(x), y, reduction="none")
                loss = (per_pixel * pixel).sum() / pixel.sum()
            else:
                loss = F.cross_entropy(model(x), y, weight=weight_t)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
            seen += len(idx)
        seconds = time.perf_counter() - started
        eval_data = val if val is not None and len(val) else train
        metrics = evaluate(model, eval_data, config.read_side, batch_size=config.batch_size)
        metrics.update(
            {
                "split": "val" if eval_data is val else "train",
                "epoch": epoch,
                "loss": float(np.mean(losses)),
                "loss_first": losses[0],
                "loss_last": losses[-1],
                "train_images_per_second": seen / seconds if seconds > 0 else None,
                "train_seconds": seconds,
            }
        )
        history.append({k: metrics[k] for k in ("epoch", "loss", "pixel_accuracy", "mean_iou")})
        log.info(
            "substance net epoch %d/%d: loss %.4f, %s pixel accuracy %.3f, mIoU %s, %.1f img/s",
            epoch, config.epochs, metrics["loss"], metrics["split"], metrics["pixel_accuracy"] or 0.0,
            metrics["mean_iou"], metrics["train_images_per_second"] or 0.0,
        )
        last = {
            "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
            "optimizer": optimizer.state_dict(),
            "epoch": epoch,
            "config": config.to_dict(),
            "architecture": config.architecture,
            "labels": list(SUBSTANCE_LABELS),
            "class_weights": weights.tolist(),
            "metrics": metrics,
            "history": history,
        }
        epochs_run.append(epoch)
        if on_epoch is not None:
            on_epoch(last, metrics)
    if last is None:
        raise ValueError("nothing to train: config.epochs is 0")
    return TrainResult(model=model.eval(), checkpoint=last, epochs_run=epochs_run, history=history)


@torch.inference_mode()
def predict_substances(model: SubstanceNet, image_rgb: np.ndarray, size: int, flip: bool = True,
                       bn_prior: float | None = None) -> np.ndarray:
    """Per-pixel substance probabilities (6, H, W) float32 at the image's own resolution.

    The image (H, W, 3; uint8, uint16 or float in [0, 1]) is resized to size x size for the network and the
    softmax is resized back bilinearly (a convex combination, so each pixel still sums to 1). With
    `flip` the softmax is averaged with that of the mirrored image (mirrored back): substances do not
    depend on left and right, and the network was trained with flips, so the two views are equally
    valid and their mean is a less noisy estimate, for one more forward pass. `bn_prior`: BatchNorm
    statistics mixed with this image's own (`classify.bn_adapt`; None: as trained).
    """
    image = np.asarray(image_rgb)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    image = image[..., :3]
    h, w = image.shape[:2]
    if image.dtype == np.uint8:
        as_float = image.astype(np.float32) / 255.0
    elif image.dtype == np.uint16:
        as_float = image.astype(np.float32) / 65535.0
    else:
        as_float = np.clip(image.astype(np.float32), 0.0, 1.0)
    import cv2

    interp = cv2.INTER_AREA if min(h, w) > size else cv2.INTER_LINEAR
    resized = cv2.resize(as_float, (size, size), interpolation=interp)
    device = next(model.parameters()).device
    was_training = model.training
    model.eval()
    views = [resized, resized[:, ::-1]] if flip else [resized]
    with adapted_batchnorm(model, bn_prior, 1) as adapted:
        logits = adapted(_to_tensor([np.ascontiguousarray(v) for v in views]).to(device))
    model.train(was_training)
    probs = torch.softmax(logits, dim=1)
    if flip:
        probs = 0.5 * (probs[:1] + probs[1:].flip(-1))
    if (h, w) != (size, size):
        probs = F.interpolate(probs, size=(h, w), mode="bilinear", align_corners=False)
    return probs[0].cpu().numpy().astype(np.float32)
