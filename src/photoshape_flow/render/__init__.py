"""Rendering with Mitsuba 3 (llvm variant): scenes as data, exact part maps, fast viewpoint sweeps.

This package's namespace is the plain data: ``from photoshape_flow.render import Camera, MaterialSpec,
UVTransform, EnvmapSpec`` never loads Mitsuba. The Mitsuba-backed code is imported from its own
module, so that only its users pay for Mitsuba: `render.renderer.Renderer` (built through
`render.factory`), `render.scene.build_scene`, and `render.selftest.check_llvm` (the ``photoshape
doctor`` self-test).
"""

from __future__ import annotations

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

__all__ = [
    "Camera",
    "EnvmapSpec",
    "MaterialSpec",
    "Refinement",
    "RendererUnavailableError",
    "UVTransform",
    "linear_to_srgb",
    "material_from_builtin",
    "srgb_to_linear",
    "uv_matrix",
]

