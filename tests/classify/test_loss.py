"""The uncertainty-weighted multitask loss against a hand computation, and its optimizer groups."""

from __future__ import annotations

import math

import pytest
import torch

from photoshape_flow.classify.configs import get_config
from photoshape_flow.classify.loss import MultitaskLoss
from photoshape_flow.classify.resnet import build_model
from photoshape_flow.classify.train import make_optimizer

MAT_LOGITS = torch.tensor([[2.0, 0.5, -1.0], [0.0, 1.0, 3.0]])
MAT_TARGET = torch.tensor([1, 2])
SUB_LOGITS = torch.tensor([[0.2, 1.2], [1.5, -0.5]])
SUB_TARGET = torch.tensor([1, 1])


def _ce(logits: list[float], target: int) -> float:
    return -math.log(math.exp(logits[target]) / sum(math.exp(v) for v in logits))


def _hand_terms() -> tuple[float, float]:
    l_mat = (_ce([2.0, 0.5, -1.0], 1) + _ce([0.0, 1.0, 3.0], 2)) / 2
    l_sub = (_ce([0.2, 1.2], 1) + _ce([1.5, -0.5], 1)) / 2
    return l_mat, l_sub


def test_uncertainty_loss_matches_hand_computation_at_init() -> None:
    loss = MultitaskLoss()
    assert loss.log_var_material.item() == 0.0 and loss.log_var_substance.item() == -1.0
    out = loss(MAT_LOGITS, SUB_LOGITS, MAT_TARGET, SUB_TARGET)
    l_mat, l_sub = _hand_terms()
    expected = l_mat * math.exp(0.0) + 0.0 + l_sub * math.exp(1.0) - 1.0
    assert out.total.item() == pytest.approx(expected, rel=1e-6)
    assert float(out.material) == pytest.approx(l_mat, rel=1e-6)
    assert float(out.substance) == pytest.approx(l_sub, rel=1e-6)


def test_uncertainty_loss_gradient_of_log_variances() -> None:
    loss = MultitaskLoss(init_log_var_material=0.3, init_log_var_substance=-0.7)
    out = loss(MAT_LOGITS, SUB_LOGITS, MAT_TARGET, SUB_TARGET)
    out.total.backward()
    l_mat, l_sub = _hand_terms()
    # dL/ds = 1 - L exp(-s)
    assert float(loss.log_var_material.grad) == pytest.approx(1 - l_mat * math.exp(-0.3), rel=1e-5)
    assert float(loss.log_var_substance.grad) == pytest.approx(1 - l_sub * math.exp(0.7), rel=1e-5)


def test_fixed_weights_and_disabled_substance_task() -> None:
    l_mat, l_sub = _hand_terms()
    fixed = MultitaskLoss(mode="fixed", material_weight=1.0, substance_weight=0.25)
    assert not fixed.learned_parameters()
    out = fixed(MAT_LOGITS, SUB_LOGITS, MAT_TARGET, SUB_TARGET)
    assert out.total.item() == pytest.approx(l_mat + 0.25 * l_sub, rel=1e-6)
    no_sub = MultitaskLoss(substance_weight=0.0)  # Table 4, "sub = N"
    out = no_sub(MAT_LOGITS, SUB_LOGITS, MAT_TARGET, SUB_TARGET)
    assert out.total.item() == pytest.approx(l_mat, rel=1e-6)
    with pytest.raises(ValueError, match="loss mode"):
        MultitaskLoss(mode="sum")  # type: ignore[arg-type]


def test_log_variances_are_not_weight_decayed() -> None:
    model = build_model("resnet18", 2, width=8, seed=0)
    loss = MultitaskLoss()
    for name in ("sgd", "adam"):
        optimizer = make_optimizer(model, loss, get_config("tiny", optimizer=name, weight_decay=1e-4))
        groups = optimizer.param_groups
        assert len(groups) == 2
        assert groups[0]["weight_decay"] == 1e-4 and len(groups[0]["params"]) == len(list(model.parameters()))
        assert groups[1]["weight_decay"] == 0.0
        assert {id(p) for p in groups[1]["params"]} == {id(loss.log_var_material), id(loss.log_var_substance)}
    sgd = make_optimizer(model, loss, get_config("paper"))
    assert isinstance(sgd, torch.optim.SGD)
    assert sgd.param_groups[0]["lr"] == 1e-4 and sgd.param_groups[0]["momentum"] == 0.9
