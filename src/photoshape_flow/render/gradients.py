"""The beauty scene with some parts' base colour and roughness driven by differentiable parameters.

Why here and not a scene of its own: `Renderer.beauty` renders one persistent scene per process
(`pool.BeautyPool`); building another for gradients would describe the materials, UVs and envmap a
second time and compile a second forward kernel. `GradientScene` prepares that same pool for a
render, then rewrites chosen slots' ``base_color.data`` and ``roughness.data`` as
``clip(base * tint, 0, 1)`` and ``clip(base * scale, 0, 1)`` (what `scene.refined_textures` bakes
for a `Refinement`), so gradients reach a few scalars and never the texels, and renders with a
``prb`` integrator (path replay: memory flat in the path length) of a small depth.

Checked on Mitsuba 3.9.1 / Dr.Jit 1.5 (tests/render/test_gradients.py): the pool's textures are
float tensors (a PNG loaded by the ``bitmap`` plugin would be ``TensorXu8``, without gradients,
unless ``"format": "variant"``: the pool loads every map as float32 arrays itself), and the
bitmap's ``to_uv`` is a ``ScalarAffineTransform3f``, not differentiable: UV scale and rotation are
searched with forward renders (`fit.refine`). The base textures are written back on exit, so the
pool's record of what it holds stays true. Holds the render lock while open.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import lru_cache
from typing import Any

from photoshape_flow.render.camera import Camera
from photoshape_flow.render.pool import beauty_pool, slot_key
from photoshape_flow.render.renderer import _RENDER_LOCK
from photoshape_flow.render.runtime import ensure_mitsuba
from photoshape_flow.render.scene import SceneOptions
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec


@lru_cache(maxsize=4)
def _integrator(max_depth: int) -> Any:
    """One ``prb`` integrator per depth for the process (a new object would change the kernel)."""
    return ensure_mitsuba().load_dict({"type": "prb", "max_depth": int(max_depth), "hide_emitters": True})


def _key(slot: int, texture: str) -> str:
    return f"{slot_key(slot)}.bsdf.nested_bsdf.{texture}.data"


class GradientScene:
    """A context manager: the pool set up for one render, with differentiable tints and roughness scales.

    `materials[i]` belongs to `shape.parts[i]` (built-ins resolved, as `Renderer.beauty` does);
    slots are positions in `shape.parts`.
    """

    def __init__(self, renderer: Any, shape: Any, materials: Sequence[MaterialSpec | None], camera: Camera,
                 envmap: EnvmapSpec | None, size: int, max_depth: int = 3):
        self.renderer = renderer
        self.shape = shape
        self.materials = renderer.resolve_materials(shape, materials)
        self.camera = camera
        self.envmap = envmap
        self.size = int(size)
        self.max_depth = int(max_depth)
        self._base: dict[str, Any] = {}

    def __enter__(self) -> GradientScene:
        self._lock = _RENDER_LOCK
        self._lock.acquire()
        try:
            renderer = self.renderer
            self.mi, self.dr = renderer.mi, renderer.dr
            self.pool = beauty_pool(len(self.shape.parts), renderer.max_depth, renderer.envmap_resolution)
            options = SceneOptions(size=self.size, spp=1, max_depth=renderer.max_depth,
                                   max_texture_size=renderer.max_texture_size)
            self.scene = self.pool.prepare(self.shape, self.materials, self.envmap, self.camera, options)
            self.params = self.pool.params
            self.integrator = _integrator(self.max_depth)
        except BaseException:
            self._lock.release()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            for key, base in self._base.items():
                self.params[key] = base
            if self._base:
                self.params.update()
            self.pool.invalidate()  # its textures were rewritten here, not by `prepare`
        finally:
            self._base = {}
            self._lock.release()

    def _original(self, key: str) -> Any:
        if key not in self._base:
            self._base[key] = self.mi.TensorXf(self.params[key])
        return self._base[key]

    def render(self, tints: Mapping[int, Any], roughness: Mapping[int, Any], spp: int, seed: int) -> Any:
        """(H, W, 4) premultiplied RGBA TensorXf with slot k's base colour times ``tints[k]`` (Color3f)
        and its roughness times ``roughness[k]`` (Float), both clipped to 0..1; gradients flow to them."""
        mi, dr = self.mi, self.dr
        for slot, tint in tints.items():
            key = _key(slot, "base_color")
            self.params[key] = dr.clip(self._original(key) * mi.TensorXf(dr.ravel(tint), shape=(1, 1, 3)), 0.0, 1.0)
        for slot, scale in roughness.items():
            key = _key(slot, "roughness")
            self.params[key] = dr.clip(self._original(key) * mi.TensorXf(dr.ravel(scale), shape=(1, 1, 1)), 0.0, 1.0)
        self.params.update()
        return mi.render(self.scene, self.params, spp=int(spp), seed=int(seed), integrator=self.integrator)
