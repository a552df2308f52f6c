"""Fixtures for renderer tests: one Renderer per session and small synthetic scenes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="session")
def renderer():  # type: ignore[no-untyped-def]
    pytest.importorskip("mitsuba")
    from photoshape_flow.render.renderer import Renderer

    return Renderer()


def write_exr(path: Path, image: np.ndarray) -> Path:
    """Write a float32 (H, W, 3) image with Mitsuba (no OpenCV EXR flag needed)."""
    import mitsuba as mi

    mi.Bitmap(np.ascontiguousarray(image, np.float32)).write(str(path))
    return path


def write_png(path: Path, image: np.ndarray) -> Path:
    import cv2

    array = np.asarray(image)
    if array.ndim == 3:
        array = array[..., ::-1]
    assert cv2.imwrite(str(path), np.ascontiguousarray(array))
    return path


@pytest.fixture
def constant_envmap(tmp_path: Path):  # type: ignore[no-untyped-def]
    """Factory: an EnvmapSpec of a uniform lat-long map with radiance `value`."""
    from photoshape_flow.render import EnvmapSpec

    def make(value: float = 1.0, name: str = "env.exr") -> EnvmapSpec:
        return EnvmapSpec(write_exr(tmp_path / name, np.full((8, 16, 3), value, np.float32)))

    return make
