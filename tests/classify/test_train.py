"""Training loop: it learns, it resumes exactly, and its metrics mean what Table 4 says."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch
from tests.classify.regiondata import TOY_MATERIALS, substance_of, write_renders
from torch import nn

from photoshape_flow.classify import checkpoint as ckpt
from photoshape_flow.classify import train as train_module
from photoshape_flow.classify.configs import AugmentConfig, get_config
from photoshape_flow.classify.dataset import RegionDataset, find_regions
from photoshape_flow.classify.resnet import build_model
from photoshape_flow.classify.train import (
    evaluate,
    learning_rate,
    select_best,
    train_classifier,
)
from photoshape_flow.vocab import SUBSTANCE_LABELS

MATERIALS = list(TOY_MATERIALS)
SUBSTANCES = [TOY_MATERIALS[m][0] for m in MATERIALS]


def _datasets(tmp_path: Path, count: int, size: int = 32, augment: AugmentConfig | None = None):
    items = write_renders(tmp_path / "renders", count, size=48)
    examples = find_regions(items, MATERIALS, substance_of())
    return RegionDataset(items, examples, size, augment, seed=3)


def test_overfits_a_tiny_batch(tmp_path: Path) -> None:
    data = _datasets(tmp_path, 3)
    data.examples = data.examples[:8]
    config = get_config("tiny", epochs=20, batch_size=8, max_steps_per_epoch=1, lr=3e-3)
    model = build_model(config.arch, len(MATERIALS), width=config.width, seed=0)
    result = train_classifier(model, data, None, config, materials=MATERIALS, material_substances=SUBSTANCES)
    losses = [h["train_material_loss"] for h in result.history]
    assert len(losses) == 20
    assert losses[-1] < 0.5 * losses[0], losses
    assert result.epoch == 20


@pytest.mark.parametrize("optimizer", ["sgd", "adam"])
def test_resume_from_checkpoint_matches_uninterrupted_run(tmp_path: Path, optimizer: str) -> None:
    data = _datasets(tmp_path, 8, augment=AugmentConfig())
    config = get_config("tiny", epochs=3, batch_size=4, max_steps_per_epoch=2, optimizer=optimizer, lr=1e-2,
                        weight_decay=1e-4)
    saved: list[dict[str, Any]] = []

    def fresh():  # type: ignore[no-untyped-def]
        return build_model(config.arch, len(MATERIALS), width=config.width, seed=0)

    full = train_classifier(fresh(), data, None, config, materials=MATERIALS, material_substances=SUBSTANCES,
                            save=saved.append)
    assert [c["epoch"] for c in saved] == [1, 2, 3]

    # "crash" after epoch 1: a new process loads the serialised epoch-1 checkpoint and continues
    first = train_classifier(fresh(), data, None, config, materials=MATERIALS, material_substances=SUBSTANCES,
                             stop_after_epochs=1)
    assert first.epoch == 1
    restored = ckpt.load(ckpt.to_bytes(first.checkpoint))  # type: ignore[arg-type]
    resumed = train_classifier(ckpt.build_model(restored), data, None, config, materials=MATERIALS,
                               material_substances=SUBSTANCES, resume=restored)
    assert resumed.epoch == 3 and len(resumed.history) == 3
    for key, value in full.model.state_dict().items():
        assert torch.equal(value, resumed.model.state_dict()[key]), key
    assert torch.equal(full.loss.log_var_substance, resumed.loss.log_var_substance)
    assert [h["train_loss"] for h in full.history] == [h["train_loss"] for h in resumed.history]
    # the epoch-2 checkpoint of the uninterrupted run equals the resumed run's state after its first step
    assert saved[1]["history"][-1]["train_loss"] == resumed.history[1]["train_loss"]


class _FixedLogits(nn.Module):
    """Returns stored logits for the example whose index is written in pixel (0, 0) of channel 0."""

    def __init__(self, material: list[list[float]], substance: list[list[float]]):
        super().__init__()
        self.material = torch.tensor(material)
        self.substance = torch.tensor(substance)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        index = x[:, 0, 0, 0].long()
        return self.material[index], self.substance[index]


def test_table4_metrics_by_hand() -> None:
    materials_substances = ["wood", "wood", "metal"]  # outputs 1, 2, 3
    wood, metal = SUBSTANCE_LABELS.index("wood"), SUBSTANCE_LABELS.index("metal")
    model = _FixedLogits(
        material=[[0.0, 2.0, 1.9, 2.1], [5.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]],
        substance=[[0, 0, 0, 3.0, 1.0, 0], [9.0, 0, 0, 0, 1.0, 0], [0, 0, 0, 0, 0, 0]],
    )

    def example(index: int, label: int, substance: int) -> tuple[torch.Tensor, int, int]:
        x = torch.zeros(4, 2, 2)
        x[0, 0, 0] = index
        return x, label, substance

    # example 0: wood material 1, top-1 is metal (wrong) but wood mass 0.57 > metal (sub-mtl right)
    # example 1: metal material 3; background has the highest logit but is never ranked
    # example 2: a background example, ignored by the metrics
    data = [example(0, 1, wood), example(1, 3, metal), example(2, 0, 0)]
    metrics = evaluate(model, data, materials_substances, batch_size=2)  # type: ignore[arg-type]
    assert metrics["val_examples"] == 2
    assert metrics["mtl@1"] == 0.5 and metrics["mtl@5"] == 1.0
    assert metrics["sub@1"] == 1.0 and metrics["sub-mtl@1"] == 1.0


def test_too_little_data_is_refused(tmp_path: Path) -> None:
    data = _datasets(tmp_path, 1)
    data.examples = data.examples[:1]
    config = get_config("tiny")
    model = build_model(config.arch, len(MATERIALS), width=config.width, seed=0)
    with pytest.raises(ValueError, match="at least 2"):
        train_classifier(model, data, None, config, materials=MATERIALS, material_substances=SUBSTANCES)


def test_cosine_schedule_runs_from_lr_to_the_floor() -> None:
    config = get_config("tiny", lr=1e-2, lr_schedule="cosine", lr_floor=0.1)
    rates = [learning_rate(config, step, 11) for step in range(11)]
    assert rates[0] == pytest.approx(1e-2) and rates[-1] == pytest.approx(1e-3)
    assert rates[5] == pytest.approx(5.5e-3)  # half way: the mean of lr and floor
    assert all(a > b for a, b in zip(rates, rates[1:], strict=False))
    assert learning_rate(get_config("tiny", lr=1e-2), 7, 11) == 1e-2  # constant: the paper's fixed rate
    with pytest.raises(ValueError, match="lr_schedule"):
        learning_rate(get_config("tiny", lr_schedule="step"), 0, 10)


def test_best_validation_epoch_is_kept_across_a_resume(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    train = _datasets(tmp_path / "t", 6, augment=AugmentConfig())
    val = _datasets(tmp_path / "v", 4)
    config = get_config("tiny", epochs=4, batch_size=4, max_steps_per_epoch=2, select_metric="mtl@1")
    # validation scores scripted per epoch: the best is epoch 2, later epochs are worse
    scores = iter([0.25, 0.75, 0.5, 0.5, 0.25, 0.75, 0.5, 0.5])

    def scripted(*args: Any, **kwargs: Any) -> dict[str, Any]:
        return {"mtl@1": next(scores), "mtl@5": 1.0, "sub@1": 0.5, "sub-mtl@1": 0.5}

    monkeypatch.setattr(train_module, "evaluate", scripted)
    snapshots: list[dict[str, torch.Tensor]] = []

    def fresh():  # type: ignore[no-untyped-def]
        return build_model(config.arch, len(MATERIALS), width=config.width, seed=0)

    full = train_classifier(fresh(), train, val, config, materials=MATERIALS, material_substances=SUBSTANCES,
                            save=lambda c: snapshots.append(c["model"]))
    assert full.best_epoch == 2 and full.epoch == 4
    assert full.metrics["epoch"] == 2 and full.metrics["mtl@1"] == 0.75
    chosen = select_best(full.checkpoint)  # type: ignore[arg-type]
    assert chosen["selected_epoch"] == 2 and chosen["epoch"] == 4 and "best" not in chosen
    for key, value in snapshots[1].items():  # the epoch-2 weights, not the last ones
        assert torch.equal(chosen["model"][key], value), key
    assert not all(torch.equal(snapshots[3][k], v) for k, v in chosen["model"].items())

    # interrupted after epoch 3 and resumed from the serialised checkpoint: still epoch 2's weights
    first = train_classifier(fresh(), train, val, config, materials=MATERIALS, material_substances=SUBSTANCES,
                             stop_after_epochs=3)
    restored = ckpt.load(ckpt.to_bytes(first.checkpoint))  # type: ignore[arg-type]
    resumed = train_classifier(ckpt.build_model(restored), train, val, config, materials=MATERIALS,
                               material_substances=SUBSTANCES, resume=restored)
    assert resumed.best_epoch == 2
    reloaded = select_best(resumed.checkpoint)  # type: ignore[arg-type]
    for key, value in chosen["model"].items():
        assert torch.equal(reloaded["model"][key], value), key


def test_workers_start_from_a_fork_server_once_a_gpu_is_driven(tmp_path: Path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Forking a process that drives CUDA can deadlock its workers, so on cuda they start from a fork
    server: the dataset must then cross a pickle. Trained here with the fork server forced on the CPU,
    the same losses as with forked workers."""
    assert train_module.worker_context(2, "cuda") == "forkserver"
    assert train_module.worker_context(0, "cuda") is None and train_module.worker_context(2, "cpu") is None
    data = _datasets(tmp_path, 4)
    config = get_config("tiny", epochs=1, batch_size=4, max_steps_per_epoch=2, num_workers=1)

    def run() -> float:
        model = build_model(config.arch, len(MATERIALS), width=config.width, seed=0)
        result = train_classifier(model, data, data, config, materials=MATERIALS, material_substances=SUBSTANCES)
        return result.history[0]["train_loss"]

    forked = run()
    asked: list[int] = []

    def fork_server(workers: int, device: Any) -> str | None:
        asked.append(workers)
        return "forkserver" if workers else None

    monkeypatch.setattr(train_module, "worker_context", fork_server)
    assert run() == pytest.approx(forked, rel=1e-5)
    assert asked and all(w == 1 for w in asked)  # the loaders did start their worker from the fork server
