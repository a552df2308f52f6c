"""Material classifier throughput: training images/s and inference masks/s.

For ResNet-18/34 (4-channel input, both heads) at 64/128/224 px, and the part recogniser on
EfficientNet-Lite0/Lite2 (`--archs efficientnet-lite0`; the size is then the part crop the backbone
reads, the frame is 128 px, stages 4-7 fine-tuned), on the CPU, and on CUDA when torch sees a GPU:

* train: forward + backward + SGD step (momentum, weight decay) on a random batch, train mode;
* infer (net): forward in eval mode under `torch.inference_mode` on a batch of inputs;
* infer (predict): `MaterialClassifier.predict` on one 256x256 image with `batch` masks, i.e. with
  the per-mask preprocessing (square pad, resize) that the inference stage pays; single view (the
  pipeline also classifies each region's mirror image, `flip=True`: two forward passes per mask).

Usage::

    .venv/bin/python bench/classifier.py                       # full grid
    .venv/bin/python bench/classifier.py --iters 2 --batch 8   # reduced scale (2-core CI box)

Writes bench/results/classifier.json and prints a table. The machine's load average is recorded:
on a shared box the numbers are lower bounds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from photoshape_flow.classify.configs import get_config
from photoshape_flow.classify.infer import MaterialClassifier
from photoshape_flow.classify.loss import MultitaskLoss
from photoshape_flow.classify.networks import build_network

NUM_MATERIALS = 100


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _timed(fn, iters: int, warmup: int, device: torch.device) -> float:  # type: ignore[no-untyped-def]
    for _ in range(warmup):
        fn()
    _sync(device)
    started = time.perf_counter()
    for _ in range(iters):
        fn()
    _sync(device)
    return (time.perf_counter() - started) / iters


def bench_one(arch: str, size: int, batch: int, iters: int, warmup: int, device: torch.device) -> dict:
    backbone = arch.startswith("efficientnet-lite")
    config = get_config("backbone", arch=arch, crop_size=size) if backbone else get_config("cpu", arch=arch)
    model = build_network(config, NUM_MATERIALS, seed=0).to(device)
    loss_fn = MultitaskLoss().to(device)
    trainable = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.SGD(
        [{"params": trainable, "weight_decay": 1e-4}, {"params": loss_fn.learned_parameters(), "weight_decay": 0.0}],
        lr=1e-4, momentum=0.9,
    )
    frame = 128 if backbone else size
    x = torch.rand(batch, 4, frame, frame, device=device)
    x[:, 3] = 0
    x[:, 3, frame // 4:3 * frame // 4, frame // 4:3 * frame // 4] = 1  # a part: the recogniser crops to it
    y_mat = torch.randint(0, NUM_MATERIALS + 1, (batch,), device=device)
    y_sub = torch.randint(0, 6, (batch,), device=device)

    def train_step() -> None:
        mat, sub = model(x)
        out = loss_fn(mat, sub, y_mat, y_sub)
        optimizer.zero_grad(set_to_none=True)
        out.total.backward()
        optimizer.step()

    model.train()
    train_s = _timed(train_step, iters, warmup, device)

    model.eval()

    def infer_step() -> None:
        with torch.inference_mode():
            model(x)

    infer_s = _timed(infer_step, iters, warmup, device)

    classifier = MaterialClassifier(model, list(range(1, NUM_MATERIALS + 1)), ["wood"] * NUM_MATERIALS, frame,
                                    device=device, batch_size=batch, flip=False)
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (256, 256, 3), dtype=np.uint8)
    masks = []
    for k in range(batch):
        mask = np.zeros((256, 256), bool)
        y0 = (k * 23) % 200
        mask[y0:y0 + 48, 40:200] = True
        masks.append(mask)
    predict_s = _timed(lambda: classifier.predict(image, masks), iters, warmup, device)
    return {
        "arch": arch, "size": size, "batch": batch, "device": str(device),
        "train_images_per_s": batch / train_s, "train_s_per_batch": train_s,
        "infer_masks_per_s": batch / infer_s, "predict_masks_per_s": batch / predict_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--archs", nargs="+", default=["resnet18", "resnet34"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[64, 128, 224])
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--iters", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--devices", nargs="+", default=["cpu", "cuda"], help="where to run (cuda if present)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "classifier.json")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = [torch.device(d) for d in args.devices if d != "cuda" or torch.cuda.is_available()]
    rows = []
    for device in devices:
        for arch in args.archs:
            for size in args.sizes:
                load_before = os.getloadavg()[0]
                row = bench_one(arch, size, args.batch, args.iters, args.warmup, device)
                row["load_average_1min"] = round((load_before + os.getloadavg()[0]) / 2, 2)
                rows.append(row)
                print(f"{row['device']:>5} {arch:>8} {size:>4}px  train {row['train_images_per_s']:8.1f} img/s  "
                      f"infer {row['infer_masks_per_s']:8.1f} masks/s  predict {row['predict_masks_per_s']:8.1f} "
                      f"masks/s  (load {row['load_average_1min']})", flush=True)
    result = {
        "benchmark": "material classifier throughput",
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "machine": platform.processor() or platform.machine(),
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "batch": args.batch, "iters": args.iters, "warmup": args.warmup, "num_materials": NUM_MATERIALS,
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
