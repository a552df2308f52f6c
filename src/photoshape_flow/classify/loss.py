"""The multitask loss of section 5.2: material and substance cross-entropies with learned weights.

Uncertainty weighting (Kendall et al. 2018, the paper's equation with log-variances s = log sigma^2):

    L = w_m (L_mat exp(-s_m) + s_m) + w_s (L_sub exp(-s_s) + s_s),    s_m = 0, s_s = -1 at the start.

`w_m`, `w_s` default to 1 (the paper's loss). Unlike the original code, where the task weights were
silently ignored under uncertainty weighting (bug 5 of the research notes), they apply in both modes:
``w_s = 0`` removes the substance task (Table 4's "sub = N" rows). ``mode="fixed"`` is the plain
weighted sum ``w_m L_mat + w_s L_sub`` with the log-variances frozen. The log-variances must not be
weight-decayed (the original decayed them): `train.make_optimizer` puts them in their own group.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

LossMode = Literal["uncertainty", "fixed"]


@dataclass
class LossOutput:
    total: torch.Tensor
    material: torch.Tensor
    substance: torch.Tensor


class MultitaskLoss(nn.Module):
    """Material + substance cross-entropy, uncertainty-weighted (learned log-variances) or fixed."""

    def __init__(
        self,
        mode: LossMode = "uncertainty",
        material_weight: float = 1.0,
        substance_weight: float = 1.0,
        init_log_var_material: float = 0.0,
        init_log_var_substance: float = -1.0,
    ):
        super().__init__()
        if mode not in ("uncertainty", "fixed"):
            raise ValueError(f"unknown loss mode {mode!r}; expected 'uncertainty' or 'fixed'")
        self.mode = mode
        self.material_weight = float(material_weight)
        self.substance_weight = float(substance_weight)
        learned = mode == "uncertainty"
        self.log_var_material = nn.Parameter(torch.tensor(float(init_log_var_material)), requires_grad=learned)
        self.log_var_substance = nn.Parameter(torch.tensor(float(init_log_var_substance)), requires_grad=learned)

    def forward(
        self,
        material_logits: torch.Tensor,
        substance_logits: torch.Tensor,
        material_target: torch.Tensor,
        substance_target: torch.Tensor,
    ) -> LossOutput:
        l_mat = F.cross_entropy(material_logits, material_target)
        l_sub = F.cross_entropy(substance_logits, substance_target)
        if self.mode == "fixed":
            total = self.material_weight * l_mat + self.substance_weight * l_sub
        else:
            s_m, s_s = self.log_var_material, self.log_var_substance
            total = self.material_weight * (l_mat * torch.exp(-s_m) + s_m)
            if self.substance_weight:
                total = total + self.substance_weight * (l_sub * torch.exp(-s_s) + s_s)
        return LossOutput(total=total, material=l_mat.detach(), substance=l_sub.detach())

    def learned_parameters(self) -> list[nn.Parameter]:
        """The log-variances when they are learned (for the optimizer's no-decay group)."""
        return [p for p in (self.log_var_material, self.log_var_substance) if p.requires_grad]
