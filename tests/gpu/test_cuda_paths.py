"""The CUDA code paths of the networks and the descriptor search, run on a real GPU.

Every test is marked ``gpu`` and skipped where torch sees no CUDA device (CI). They train and run the
project's own functions (`train_classifier`, `load_classifier`, `train_substance_net`,
`predict_substances`, `resolve_device`, `align.retrieval.search` as `pipeline/coarse/pairs.py`
calls it) on cuda and compare with the CPU run of the same weights / data.

``PHOTOSHAPE_GPU_TEST_DEVICE=cpu`` runs them with "cpu" in place of "cuda" and no skip, to check
their logic on a machine without a GPU (the CPU-vs-"device" comparisons are then exact).

Tolerances: cuDNN convolutions use TF32 by default on Ampere and newer (the pipeline keeps that
default), so the default-precision comparison allows 3e-2 in probabilities; with TF32 switched off
the same comparison must hold to 1e-4.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

try:
    from tests.classify.regiondata import (
        SUBSTANCE_COLOURS,
        TOY_MATERIALS,
        render_arrays,
        substance_of,
        toy_substances,
        write_renders,
    )
except ImportError:  # an installed package named "tests" shadows this repository's
    import importlib.util

    _path = Path(__file__).parents[1] / "classify" / "regiondata.py"
    _spec = importlib.util.spec_from_file_location("_regiondata", _path)
    _regiondata = importlib.util.module_from_spec(_spec)  # type: ignore[arg-type]
    _spec.loader.exec_module(_regiondata)  # type: ignore[union-attr]
    TOY_MATERIALS, render_arrays = _regiondata.TOY_MATERIALS, _regiondata.render_arrays
    substance_of, write_renders = _regiondata.substance_of, _regiondata.write_renders
    SUBSTANCE_COLOURS, toy_substances = _regiondata.SUBSTANCE_COLOURS, _regiondata.toy_substances

from photoshape_flow.align.index import ArrayDatabase, ShardListDatabase
from photoshape_flow.align.retrieval import brute_force, recall_at_k, search
from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify.configs import AugmentConfig
from photoshape_flow.classify.configs import get_config as classifier_config
from photoshape_flow.classify.dataset import RegionDataset, find_regions
from photoshape_flow.classify.infer import load_classifier
from photoshape_flow.classify.networks import build_network
from photoshape_flow.classify.resnet import build_model
from photoshape_flow.classify.substance_configs import get_config as substance_config
from photoshape_flow.classify.substance_net import NUM_CLASSES
from photoshape_flow.classify.substance_train import (
    checkpoint_from_bytes,
    checkpoint_to_bytes,
    load_model,
    predict_substances,
    train_substance_net,
)
from photoshape_flow.classify.train import train_classifier
from photoshape_flow.devices import resolve_device
from photoshape_flow.vocab import SUBSTANCE_LABELS

pytestmark = pytest.mark.gpu

DEVICE = os.environ.get("PHOTOSHAPE_GPU_TEST_DEVICE", "cuda")
MATERIALS = list(TOY_MATERIALS)
SUBSTANCES = [TOY_MATERIALS[m][0] for m in MATERIALS]
LOOSE = 3e-2  # default precision (TF32 convolutions) vs CPU float32, in probabilities
STRICT = 1e-4  # TF32 off vs CPU float32


@pytest.fixture
def device() -> str:
    if DEVICE.startswith("cuda") and not torch.cuda.is_available():
        pytest.skip("torch sees no CUDA device (PHOTOSHAPE_GPU_TEST_DEVICE=cpu runs these on the CPU)")
    return DEVICE


@contextlib.contextmanager
def no_tf32() -> Iterator[None]:
    """float32 convolutions and matrix products at full precision on the GPU (no-op on the CPU)."""
    saved = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = saved


def _on(module: torch.nn.Module, device: str) -> bool:
    return all(p.device.type == torch.device(device).type for p in module.parameters())


def _all_cpu(value: object) -> bool:
    if isinstance(value, torch.Tensor):
        return value.device.type == "cpu"
    if isinstance(value, dict):
        return all(_all_cpu(v) for v in value.values())
    if isinstance(value, list | tuple):
        return all(_all_cpu(v) for v in value)
    return True


def _report(name: str, value: float) -> None:
    print(f"GPU-TEST {name} = {value:.3g}")


# -- material classifier ------------------------------------------------------------------------------


def _region_sets(tmp_path: Path, count: int = 6) -> tuple[RegionDataset, RegionDataset]:
    items = write_renders(tmp_path / "renders", count, size=48)
    examples = find_regions(items, MATERIALS, substance_of())
    return (RegionDataset(items, examples, 32, AugmentConfig(), seed=3),
            RegionDataset(items, examples, 32, None, seed=3))


def _photo_and_masks() -> tuple[np.ndarray, list[np.ndarray]]:
    """A toy render not seen in training, padded to a non-square image, and one mask per region."""
    image, ids = render_arrays(50, 48, TOY_MATERIALS, seed=7)
    image = np.concatenate([image, np.full((48, 16, 3), 255, np.uint8)], axis=1)
    ids = np.concatenate([ids, np.zeros((48, 16), ids.dtype)], axis=1)
    return image, [ids == m for m in np.unique(ids) if m]


def _compare_predictions(on_device, on_cpu, image, masks, label: str) -> None:  # type: ignore[no-untyped-def]
    for crop in ("image", "mask"):
        mat_d, sub_d = on_device.predict(image, masks, crop=crop)
        mat_c, sub_c = on_cpu.predict(image, masks, crop=crop)
        assert mat_d.shape == mat_c.shape == (len(masks), len(MATERIALS) + 1)
        assert sub_d.shape == sub_c.shape == (len(masks), len(SUBSTANCE_LABELS))
        assert np.isfinite(mat_d).all() and np.isfinite(sub_d).all()
        assert np.allclose(mat_d.sum(1), 1.0, atol=1e-4) and np.allclose(sub_d.sum(1), 1.0, atol=1e-4)
        diff = max(float(np.abs(mat_d - mat_c).max()), float(np.abs(sub_d - sub_c).max()))
        _report(f"classifier {label} crop={crop} max |p_dev - p_cpu|", diff)
        assert diff < LOOSE
        with no_tf32():
            mat_s, sub_s = on_device.predict(image, masks, crop=crop)
        strict = max(float(np.abs(mat_s - mat_c).max()), float(np.abs(sub_s - sub_c).max()))
        _report(f"classifier {label} crop={crop} max |p_dev - p_cpu| without TF32", strict)
        assert strict < STRICT
        # the ranking the pipeline takes from them agrees wherever the top two are not near a tie
        top2 = np.sort(mat_c[:, 1:], axis=1)[:, -2:]
        clear = top2[:, 1] - top2[:, 0] > 2 * LOOSE
        assert (mat_d[clear, 1:].argmax(1) == mat_c[clear, 1:].argmax(1)).all()


@pytest.mark.parametrize("arch", ["resnet18", "efficientnet-lite0"])
def test_material_classifier_trains_resumes_and_infers_on_device(tmp_path: Path, device: str, arch: str) -> None:
    """Both network families: the from-scratch ResNet and the part recogniser on its ImageNet backbone."""
    train, val = _region_sets(tmp_path)
    config = classifier_config("tiny", epochs=2, batch_size=8, max_steps_per_epoch=3, arch=arch, crop_size=64)
    saved: list[dict] = []
    result = train_classifier(
        build_network(config, len(MATERIALS), seed=0), train, val, config,
        materials=MATERIALS, material_substances=SUBSTANCES, device=device, save=saved.append,
    )
    assert result.epoch == 2 and [c["epoch"] for c in saved] == [1, 2]
    assert _on(result.model, device) and _on(result.loss, device)
    for entry in result.history:
        assert entry["steps"] >= 1 and entry["images"] == 8 * entry["steps"]
        assert math.isfinite(entry["train_loss"]) and math.isfinite(entry["val_material_loss"])
        assert entry["val_examples"] == len(val)
        assert all(0.0 <= entry[key] <= 1.0 for key in ("mtl@1", "mtl@5", "sub@1", "sub-mtl@1"))
    # checkpoints hold CPU tensors only (model, optimizer state, log-variances), whatever the device
    assert all(_all_cpu(c) for c in saved)

    # resume from the serialised epoch-1 checkpoint on the device: the optimizer state moves there
    restored = ckpt.load(ckpt.to_bytes(saved[0]))
    resumed = train_classifier(
        ckpt.build_model(restored), train, val, config, materials=MATERIALS, material_substances=SUBSTANCES,
        device=device, resume=restored,
    )
    assert resumed.epoch == 2 and len(resumed.history) == 2 and _on(resumed.model, device)
    # same batches and augmentations; on cuda only the kernels' summation order may differ
    assert resumed.history[1]["train_loss"] == pytest.approx(result.history[1]["train_loss"], rel=0.05)

    blob = ckpt.to_bytes(ckpt.slim(result.checkpoint))  # type: ignore[arg-type]
    on_device = load_classifier(blob, device=device)
    on_cpu = load_classifier(blob, device="cpu")
    assert on_device.device.type == torch.device(device).type and _on(on_device.model, device)
    assert not on_device.model.training
    if device.startswith("cuda"):  # the default, settings.device = "auto", picks the GPU
        assert load_classifier(blob).device.type == "cuda"
    image, masks = _photo_and_masks()
    _compare_predictions(on_device, on_cpu, image, masks, arch)


def test_material_classifier_paper_options_on_device(tmp_path: Path, device: str) -> None:
    """channels_last and DataLoader workers with pinned memory, as the "paper" (CUDA) config trains."""
    import warnings

    from photoshape_flow.classify.train import worker_context

    train, val = _region_sets(tmp_path, count=4)
    config = classifier_config("tiny", epochs=1, batch_size=8, max_steps_per_epoch=2, channels_last=True,
                               num_workers=2)
    if device.startswith("cuda"):  # workers start from a fork server, not a fork of a CUDA process
        assert worker_context(config.num_workers, device) == "forkserver"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = train_classifier(
            build_model(config.arch, len(MATERIALS), width=config.width, seed=0), train, val, config,
            materials=MATERIALS, material_substances=SUBSTANCES, device=device,
        )
    assert not [w for w in caught if "fork()" in str(w.message)], [str(w.message) for w in caught]
    assert result.epoch == 1 and math.isfinite(result.history[0]["train_loss"])
    assert result.history[0]["val_examples"] == len(val)
    assert result.model.conv1.weight.is_contiguous(memory_format=torch.channels_last)
    blob = ckpt.to_bytes(ckpt.slim(result.checkpoint))  # type: ignore[arg-type]
    image, masks = _photo_and_masks()
    _compare_predictions(load_classifier(blob, device=device), load_classifier(blob, device="cpu"), image, masks,
                         "channels_last")


# -- substance network --------------------------------------------------------------------------------

def test_substance_network_trains_resumes_and_predicts_on_device(device: str) -> None:
    data, val = toy_substances(6, seed=1), toy_substances(3, seed=2)
    config = substance_config("tiny", epochs=2, iters_per_epoch=3, device=device)
    result = train_substance_net(data, val, config)
    assert result.epochs_run == [1, 2] and _on(result.model, device)
    metrics = result.checkpoint["metrics"]
    assert metrics["split"] == "val" and math.isfinite(metrics["loss"]) and 0.0 <= metrics["pixel_accuracy"] <= 1.0
    assert _all_cpu(result.checkpoint["model"])

    restored = checkpoint_from_bytes(checkpoint_to_bytes(result.checkpoint))
    assert _all_cpu(restored)
    # resume one more epoch on the device from the serialised checkpoint (optimizer state to the device)
    more = train_substance_net(data, val, substance_config("tiny", epochs=3, iters_per_epoch=3, device=device),
                               checkpoint=restored)
    assert more.epochs_run == [3] and _on(more.model, device) and math.isfinite(more.checkpoint["metrics"]["loss"])

    on_device, on_cpu = load_model(restored, device), load_model(restored, "cpu")
    assert _on(on_device, device) and not on_device.training
    image = np.random.default_rng(5).integers(0, 256, (40, 56, 3), dtype=np.uint8)  # not square, not 32 px
    image[8:30, 10:40] = SUBSTANCE_COLOURS[2]
    p_dev = predict_substances(on_device, image, config.size)
    p_cpu = predict_substances(on_cpu, image, config.size)
    assert p_dev.shape == p_cpu.shape == (NUM_CLASSES, 40, 56) and p_dev.dtype == np.float32
    assert np.isfinite(p_dev).all() and np.allclose(p_dev.sum(0), 1.0, atol=1e-4)
    diff = float(np.abs(p_dev - p_cpu).max())
    _report("substance max |p_dev - p_cpu|", diff)
    assert diff < LOOSE
    with no_tf32():
        strict = float(np.abs(predict_substances(on_device, image, config.size) - p_cpu).max())
    _report("substance max |p_dev - p_cpu| without TF32", strict)
    assert strict < STRICT
    # the model returned by training is the checkpoint's network on the device
    assert np.allclose(predict_substances(result.model, image, config.size), p_dev, atol=1e-6)


# -- device resolution and the descriptor search ----------------------------------------------------


def test_resolve_device_auto_is_cuda_with_a_gpu(device: str) -> None:
    assert resolve_device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == "cpu"
    if device.startswith("cuda"):
        assert resolve_device("auto") == "cuda"
        assert resolve_device("cuda") == "cuda" and resolve_device("cuda:0") == "cuda:0"
        assert torch.ones(2, device=resolve_device("auto")).sum().item() == 2.0


def _descriptors(seed: int = 0, shapes: int = 300, views: int = 8, dims: int = 64, queries: int = 40):
    """Small-integer float16 shards (as stored) and queries, so every float32 distance is exact on both
    devices and ties are frequent; half the queries are copies of known (shape, view) entries with
    three coordinates moved by one."""
    rng = np.random.default_rng(seed)
    db = rng.integers(-3, 4, (shapes, views, dims)).astype(np.float16)
    half = queries // 2
    planted = rng.choice(shapes, half, replace=False)
    planted_views = rng.integers(0, views, half)
    near = db[planted, planted_views].astype(np.float32)
    for row in near:
        row[rng.choice(dims, 3, replace=False)] += rng.choice([-1.0, 1.0], 3)
    far = rng.integers(-3, 4, (queries - half, dims))
    return np.concatenate([near, far]).astype(np.float32), db, planted, planted_views


@pytest.mark.parametrize("mode", ["exact", "bf16"])
def test_descriptor_search_same_neighbours_on_device_as_on_cpu(mode: str, device: str) -> None:
    q, db, planted, planted_views = _descriptors()
    k = 8
    # as pipeline/coarse/pairs.py runs it: several chunks (prefetched) and query batches
    kwargs = {"mode": mode, "chunk_rows": 512, "query_batch": 16}
    stats: dict[str, float] = {}
    dev_device = resolve_device("auto") if device.startswith("cuda") else device
    got = search(q, ArrayDatabase(db), k, device=dev_device, stats=stats, **kwargs)
    cpu = search(q, ArrayDatabase(db), k, device="cpu", **kwargs)
    shards = ShardListDatabase(list(range(len(db))), lambda i: db[i], num_views=db.shape[1], dims=db.shape[2])
    listed = search(q, shards, k, device=dev_device, **kwargs)
    want = brute_force(q, db, k)
    assert stats["chunks"] > 1
    assert any(len(set(row)) < len(row) for row in want.distances)  # there were ties to break
    for matches in (got, listed):
        assert matches.shapes.dtype == np.int64 and matches.distances.dtype == np.float32
        np.testing.assert_array_equal(matches.shapes[: len(planted), 0], planted)
        np.testing.assert_array_equal(matches.views[: len(planted), 0], planted_views)
        np.testing.assert_array_equal(matches.distances[: len(planted), 0], 3.0)
    if mode == "exact":  # exact, ties to the lower position, on every device
        for matches in (got, listed, cpu):
            np.testing.assert_array_equal(matches.shapes, want.shapes)
            np.testing.assert_array_equal(matches.views, want.views)
            np.testing.assert_array_equal(matches.distances, want.distances.astype(np.float32))
    else:  # bf16 candidates, exact float32 re-scoring: near-exact, and as good on the device as on the cpu
        recall_dev, recall_cpu = recall_at_k(want, got), recall_at_k(want, cpu)
        same_d = float((got.distances == want.distances.astype(np.float32)).mean())
        _report("search bf16 recall@8 device", recall_dev)
        _report("search bf16 recall@8 cpu", recall_cpu)
        _report("search bf16 fraction of exact distances device", same_d)
        assert recall_dev >= 0.98 and same_d >= 0.98
        assert recall_dev >= recall_cpu - 0.01
        np.testing.assert_array_equal(listed.distances, got.distances)
