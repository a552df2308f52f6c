"""Rendering with Mitsuba 3 (llvm variant): scenes as data, exact part maps, fast viewpoint sweeps.

``from photoshape_flow.render import Camera, MaterialSpec, UVTransform, EnvmapSpec, Renderer``.
`Camera` and the specs are plain data (importing them never loads Mitsuba); `Renderer` loads
Mitsuba on first use, via `photoshape_flow.render.runtime.ensure_mitsuba`. `check_llvm` (the
``photoshape doctor`` self-test) lives in `render.selftest`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from photoshape_flow.render.camera import Camera
from photoshape_flow.render.runtime import RendererUnavailableError
from photoshape_flow.render.specs import (
    EnvmapSpec,
    MaterialSpec,
    Refinement,
    UVTransform,
    linear_to_srgb,
    material_from_builtin,
    srgb_to_linear,
    uv_matrix,
)

if TYPE_CHECKING:
    from photoshape_flow.render.renderer import BeautyResult, Renderer, SweepResult
    from photoshape_flow.render.scene import SceneOptions, build_scene
    from photoshape_flow.render.selftest import check_llvm

_LAZY = {
    "Renderer": "photoshape_flow.render.renderer",
    "BeautyResult": "photoshape_flow.render.renderer",
    "SweepResult": "photoshape_flow.render.renderer",
    "build_scene": "photoshape_flow.render.scene",
    "SceneOptions": "photoshape_flow.render.scene",
    "check_llvm": "photoshape_flow.render.selftest",
}

__all__ = [
    "BeautyResult",
    "Camera",
    "EnvmapSpec",
    "MaterialSpec",
    "Refinement",
    "Renderer",
    "RendererUnavailableError",
    "SceneOptions",
    "SweepResult",
    "UVTransform",
    "build_scene",
    "check_llvm",
    "linear_to_srgb",
    "material_from_builtin",
    "srgb_to_linear",
    "uv_matrix",
]


def __getattr__(name: str) -> Any:
    """Import the Mitsuba-backed modules only when they are used."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
