"""Mitsuba start-up and the LLVM check used by `photoshape doctor`."""

from __future__ import annotations

import pytest

from photoshape_flow.render.runtime import llvm_major


def test_llvm_major_from_file_names() -> None:
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert llvm_major(None) is None


@pytest.mark.render
def test_renderer_runs_on_a_recent_llvm(renderer) -> None:  # type: ignore[no-untyped-def]
    import drjit as dr
    import mitsuba as mi

    from photoshape_flow.render.runtime import MIN_LLVM_MAJOR, loaded_llvm

    major = llvm_major(loaded_llvm())
    assert major is not None and major >= MIN_LLVM_MAJOR
    assert mi.variant() == "llvm_ad_rgb" and dr.thread_count() >= 2


@pytest.mark.render
def test_check_llvm_renders_in_a_subprocess() -> None:
    from photoshape_flow.render.selftest import check_llvm

    ok, message = check_llvm()
    assert ok, message
    assert "llvm_ad_rgb" in message and "libLLVM" in message
