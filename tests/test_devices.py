"""`devices.resolve_device`: one rule for every stage, and no silent cpu fall back when cuda is asked for."""

from __future__ import annotations

import pytest
import torch

from photoshape_flow.devices import resolve_device


def test_auto_picks_cuda_only_when_present() -> None:
    assert resolve_device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == "cpu"


def test_cuda_without_a_gpu_names_the_setting(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == "cpu"
    with pytest.raises(RuntimeError, match="PHOTOSHAPE_DEVICE"):
        resolve_device("cuda")
    with pytest.raises(RuntimeError, match="settings.device"):
        resolve_device("cuda:1")


def test_cuda_with_a_gpu_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert resolve_device("auto") == "cuda" and resolve_device("cuda:1") == "cuda:1"
