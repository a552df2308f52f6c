"""Test-time batch-norm adaptation: normalise a photo with statistics partly its own.

The networks are trained from scratch on clean renders of the project's own renderer, and every
BatchNorm layer normalises with that training set's channel statistics. A product photo differs
(another renderer or a camera, real lighting, blur, JPEG): its activations are shifted and scaled
away from those statistics, and every later layer sees inputs it was never trained on. Schneider et
al. (NeurIPS 2020, "Improving robustness against common corruptions by covariate shift adaptation")
re-estimate the statistics from the test input itself, mixed with the training ones: the training
set counts as `prior` samples, the input as `samples`, so

    mean = (N mean_train + n mean_input) / (N + n),   var = (N var_train + n var_input) / (N + n).

No label and no gradient step: only first and second moments per channel move, so the classifier's
decision boundaries stay those it learnt. With n = 1 (one photo) and N = 16 they report lower error
than the training statistics under every strong corruption. `prior=None` means no adaptation, the
network as trained; `prior=0` normalises with the input's statistics alone.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch
import torch.nn.functional as F
from torch import nn


def mixing_weight(prior: float, samples: int) -> float:
    """The input's share n / (N + n) of the adapted statistics (1 with no prior, 0 with no input)."""
    if prior < 0:
        raise ValueError(f"the prior strength must be >= 0, got {prior}")
    if samples <= 0:
        return 0.0
    return samples / (prior + samples)


def _adapted_forward(bn: nn.BatchNorm2d, weight: float):
    def forward(x: torch.Tensor) -> torch.Tensor:
        dims = (0, 2, 3)
        mean = x.mean(dims)
        var = x.var(dims, unbiased=False)
        assert bn.running_mean is not None and bn.running_var is not None
        mixed_mean = (1.0 - weight) * bn.running_mean + weight * mean
        mixed_var = (1.0 - weight) * bn.running_var + weight * var
        return F.batch_norm(x, mixed_mean, mixed_var, bn.weight, bn.bias, False, 0.0, bn.eps)

    return forward


@contextmanager
def adapted_batchnorm(model: nn.Module, prior: float | None, samples: int) -> Iterator[nn.Module]:
    """`model` whose BatchNorm2d layers normalise with training statistics mixed with the batch's.

    `samples`: how many independent inputs the batch holds (regions cut from one photo over a white
    pad are one photo: pass 1). Restores every layer on exit, whatever happens inside.
    """
    if prior is None:
        yield model
        return
    weight = mixing_weight(prior, samples)
    layers = [mod for mod in model.modules() if isinstance(mod, nn.BatchNorm2d) and mod.running_mean is not None]
    try:
        for bn in layers:
            bn.forward = _adapted_forward(bn, weight)  # type: ignore[method-assign]
        yield model
    finally:
        for bn in layers:
            del bn.forward  # back to the class's forward
