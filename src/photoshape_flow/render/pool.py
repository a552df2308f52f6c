"""One persistent beauty scene per process, rewritten in place for every render, so beauty renders of
any shape reuse the same compiled path-tracing kernel.

Why: Dr.Jit traces a virtual call (BSDF, shape, emitter) over *every live instance* of that domain in
the process, so the kernel depends on which Mitsuba objects exist and on their state. Loading a
scene per shape compiled a new ~5k-op kernel for every new shape (0.35-0.55 s of LLVM codegen,
against ~0.05 s for a 96 px, 16 spp render). A `BeautyPool` is built once and only its parameters
change (``mi.traverse`` + ``params.update()``); the exact passes' casters are created before it
(`raycast.caster_slots`), so they do not change it later either.

Measured with Dr.Jit's kernel history (drjit 1.5, Mitsuba 3.9), the kernel also depends on:
- the number of part slots: a pool holds 4, 8, 12, 16, 24, 32, 48, ... slots (`slot_count`) and only
  grows (the old pool is freed first): one new kernel per growth step, never one per shape;
- the integrator's ``max_depth`` (pool key) and the film size (set in place: one kernel per size);
- the *resolution of the environment map* (its hierarchical sampling warp unrolls one step per
  level), so every envmap is resampled to `ENVMAP_RESOLUTION` (area average when shrinking, bilinear
  when growing; the background is hidden, only the lighting uses it);
- scalar values set from Python (the envmap scale, specular), which would be literals: set opaque;
- the alignment of NumPy buffers (Dr.Jit uses packet gathers only from 64-byte aligned memory):
  every array goes through `scene.aligned`.
Data (no recompilation): mesh vertices, normals, UVs and faces of any size; bitmap textures of any
resolution (so textures keep their own resolution); the envmap's data, scale and rotation; the
camera, the number of samples and the seed; the floor.

Unused slots and the floor when it is off hold one degenerate triangle (zero area); the floor is a
40 x 40 quad mesh with the ``rectangle``'s UVs and a diffuse BSDF, rendering like `scene.floor_shape`.
``envmap=None`` is an envmap of constant radiance 1: the constant white sky, with other noise. Cost:
Dr.Jit traces every live instance on every render (a cache hit still traces), ~5 ms per slot at 2
threads, so the pool's size matters: after a 10-part shape every render carries 12 slots.

Tracing is about half of a small render's time (a 9-part shape at 120 px and 8 spp: ~90 ms traced,
~40 ms replayed), so `BeautyPool.render` freezes it (`dr.freeze`): the first render of a
configuration is traced and recorded (dearer than a plain trace where nothing replays: callers
whose every render is its own scene and seed, such as the training and bootstrap renders, pass
`record=False`, which saves them 10-19%), later ones replay the recorded kernels on
the scene's new camera, envmap rotation and scale and scalars (the small demo: 892 -> 816 s; tracing
a configuration's first render plainly and recording its second ran 878 s). A replay reads
some inputs from the recording rather than the scene (measured with `bench/frozen_render.py` on
the fit stage's own renders: a freed Embree scene after a mesh upload, the old UVs after a UV
rewrite, one wrong render after texture changes alone), so any upload of meshes, UVs, textures or
envmap pixels starts a new configuration (`version`), and the film size, spp and seed are part of
the key. What replays: a shape under other lights (the fit's lighting search), other cameras
(publish's views), the same materials again. Frozen and traced renders agree to float rounding,
not bit for bit (tests/render/test_pool.py).
"""

from __future__ import annotations

import gc
import itertools
import math
import weakref
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.raycast import caster_slots
from photoshape_flow.render.runtime import ensure_mitsuba
from photoshape_flow.render.scene import (
    SceneOptions,
    aligned,
    make_mesh,
    material_bsdf,
    material_textures,
    mitsuba_uvs,
    sensor_dict,
)
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec

ENVMAP_RESOLUTION = (256, 512)  # (height, width) every envmap is resampled to; the demo's own size
MIN_SLOTS = 4
FLOOR_HALF_SIZE = 20.0  # as `scene.floor_shape`: a rectangle scaled by 20
FLOOR_UVS = [[0, 1], [0, 0], [1, 0], [1, 1]]  # the rectangle's: u along +x, v along -z
_UNUSED = MaterialSpec("unused")
FROZEN_CONFIGURATIONS = 4  # recordings `dr.freeze` keeps (least recently used dropped)
_VERSIONS = itertools.count(1)  # process-wide, so a new pool never reuses an old pool's keys


def slot_count(parts: int) -> int:
    """Slots of a pool for `parts` parts: the smallest of 4, 8, 12, 16, 24, 32, 48, 64, ... (4 and then
    4 or 6 times a power of two) that holds them. Why not powers of two: every slot is traced on every
    render (~5 ms each at 2 threads, see the module docstring), so the ladder wastes at most a third."""
    count = MIN_SLOTS
    while count < parts:
        power = 1 << (count.bit_length() - 1)  # the largest power of two <= count
        count = 2 * power if count > power or count == MIN_SLOTS else count + power // 2
    return count


def slot_key(k: int) -> str:
    return f"slot_{k:04d}"


def _degenerate(index: int = 0) -> PartMesh:
    """One zero-area triangle at the origin. Embree reports a hit only for a ray through that exact
    point, which the path tracer's jittered samples never meet (the pool renders like a scene
    without the slot: tests/render/test_pool.py)."""
    return PartMesh(
        index=index,
        name="unused",
        vertices=np.zeros((3, 3), np.float32),
        faces=np.array([[0, 1, 2]], np.int32),
        normals=np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (3, 1)),
        uvs=np.zeros((3, 2), np.float32),
    )


def _floor_part(y: float) -> PartMesh:
    s = FLOOR_HALF_SIZE
    vertices = np.array([[-s, y, -s], [-s, y, s], [s, y, s], [s, y, -s]], np.float32)  # counter-clockwise from +y
    return PartMesh(
        index=0,
        name="floor",
        vertices=vertices,
        faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
        normals=np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (4, 1)),
        uvs=np.array(FLOOR_UVS, np.float32),
    )


def _pad_columns(rgb: np.ndarray) -> np.ndarray:
    """The layout of the ``envmap`` plugin's ``data``: one wrap-around column on each side."""
    return aligned(np.concatenate([rgb[:, -1:], rgb, rgb[:, :1]], axis=1))


@lru_cache(maxsize=16)
def _envmap_data(path: str, mtime_ns: int, resolution: tuple[int, int]) -> np.ndarray:
    """Linear RGB of an envmap file at `resolution`, in the ``envmap`` plugin's ``data`` layout."""
    del mtime_ns  # cache key only
    mi = ensure_mitsuba()
    try:
        bitmap = mi.Bitmap(path)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read environment map ({exc})") from exc
    # as the envmap plugin: RGB float, sRGB-encoded files decoded to linear
    bitmap = bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False)
    rgb = np.array(bitmap, dtype=np.float32, copy=True).reshape(bitmap.height(), bitmap.width(), 3)
    height, width = resolution
    if rgb.shape[:2] != (height, width):
        import cv2

        shrink = rgb.shape[0] >= height and rgb.shape[1] >= width
        rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return _pad_columns(np.maximum(rgb, 0.0))


@lru_cache(maxsize=4)
def _white_sky(resolution: tuple[int, int]) -> np.ndarray:
    return _pad_columns(np.ones((*resolution, 3), np.float32))


def envmap_data(envmap: EnvmapSpec | None, resolution: tuple[int, int] = ENVMAP_RESOLUTION) -> np.ndarray:
    """The pool's ``emitter.data`` for an envmap (cached by path and mtime); radiance 1 when None."""
    if envmap is None:
        return _white_sky(tuple(resolution))
    path = Path(envmap.path)
    try:
        mtime = path.stat().st_mtime_ns
    except OSError as exc:
        raise ValueError(f"{path}: environment map file missing") from exc
    return _envmap_data(str(path), mtime, tuple(resolution))


def _marker(value: Any) -> Any:
    """What `applied` keeps for a value: small arrays by content; large (cached) arrays as the object
    itself, compared by identity (kept alive here, so its id cannot be reused)."""
    if isinstance(value, np.ndarray) and value.size <= 64:
        return value.tobytes()
    return value


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return a is b
    return bool(a == b)


class BeautyPool:
    """A loaded beauty scene with `slots` part meshes, a floor, an envmap and a sensor (see module doc)."""

    def __init__(self, slots: int, max_depth: int, envmap_resolution: tuple[int, int] = ENVMAP_RESOLUTION):
        mi = ensure_mitsuba()
        import drjit as dr

        self.mi, self.dr = mi, dr
        self.slots = int(slots)
        self.max_depth = int(max_depth)
        self.envmap_resolution = (int(envmap_resolution[0]), int(envmap_resolution[1]))
        unused = _degenerate()
        zeros = np.zeros((3, 2), np.float32)
        floor_bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8] * 3}})
        scene: dict[str, Any] = {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": self.max_depth, "hide_emitters": True},
            "sensor": sensor_dict(Camera(0.0, 0.0), SceneOptions(size=16, spp=1)),
            "emitter": {"type": "envmap", "bitmap": mi.Bitmap(envmap_data(None, self.envmap_resolution)[:, 1:-1])},
            "floor": make_mesh("floor", unused, uvs=zeros, bsdf=floor_bsdf),
        }
        for k in range(self.slots):
            key = slot_key(k)
            scene[key] = make_mesh(key, unused, uvs=zeros, bsdf=mi.load_dict(material_bsdf(_UNUSED)))
        self.scene = mi.load_dict(scene)
        self.params = mi.traverse(self.scene)
        self._applied: dict[str, Any] = {}
        self._shape_ref: weakref.ref | None = None
        self._geometry = 0  # bumped whenever the slots' meshes change (their UVs depend on them)
        self.version = next(_VERSIONS)  # bumped on every upload of meshes, UVs or pixels: frozen renders' key

    def invalidate(self) -> None:
        """Start a new frozen configuration: for writers of `params` other than `prepare`
        (`render.gradients.GradientScene`), whose uploads a replay would not see (module doc)."""
        self.version = next(_VERSIONS)

    def render(self, spp: int, seed: int, record: bool = True) -> np.ndarray:
        """(H, W, 4) float32 premultiplied RGBA of the scene as `prepare` left it, frozen (module doc).

        `record=False` traces it plainly: for a caller whose every render is a new configuration or
        seed (training and bootstrap renders, material previews, the demo's photos), where a recording
        would never replay and only costs its 10-19%.
        """
        if not record:
            return np.array(self.mi.render(self.scene, spp=int(spp), seed=int(seed)), dtype=np.float32)
        state = (self.version, int(self._applied.get("sensor.film.size", 0)), int(spp), int(seed))
        return np.array(_frozen_render()(self.scene, state), dtype=np.float32)

    # -- one render --------------------------------------------------------------------------
    def prepare(
        self,
        shape: ShapeMesh,
        materials: Sequence[MaterialSpec],
        envmap: EnvmapSpec | None,
        camera: Camera,
        options: SceneOptions,
    ) -> Any:
        """Set the scene to what `scene.build_scene` describes for these arguments; returns the scene.

        Only what differs from the previous render is uploaded: meshes when the shape object
        changes, UVs when the material scale or jitter changes, textures by identity of the
        (cached) arrays, the envmap data when the file changes.
        """
        parts = shape.parts
        if len(parts) > self.slots:
            raise ValueError(f"shape has {len(parts)} parts, the pool {self.slots} slots")
        if len(materials) != len(parts):
            raise ValueError(f"need one material per part: {len(parts)} parts, {len(materials)} materials")
        jitters = options.uv_transforms
        if jitters is not None and len(jitters) != len(parts):
            raise ValueError(f"need one UV transform per part: {len(parts)} parts, {len(jitters)} transforms")
        for i, material in enumerate(materials):
            if material is None:
                raise ValueError(f"part {parts[i].index} ({parts[i].name}): no material (resolve built-ins first)")
        wanted: dict[str, Any] = {
            "sensor.to_world": camera.to_world(),
            "sensor.x_fov": float(camera.fov),
            "sensor.film.size": int(options.size),
            "emitter.data": envmap_data(envmap, self.envmap_resolution),
            "emitter.scale": float(envmap.scale) if envmap is not None else 1.0,
            "emitter.to_world": ("rotate_y", float(envmap.rotation) if envmap is not None else 0.0),
            "floor.vertex_positions": (
                ("floor", float(shape.bounds()[0][1]) - 1e-4) if options.floor else ("unused",)
            ),
            "floor.bsdf.reflectance.value": float(options.floor_albedo),
        }
        new_shape = self._shape_ref is None or self._shape_ref() is not shape
        if new_shape:
            self._geometry += 1
        for k in range(self.slots):
            key = slot_key(k)
            part = parts[k] if k < len(parts) and len(parts[k].faces) > 0 else None
            wanted[f"{key}.geometry"] = ("part", self._geometry) if part is not None else ("unused",)
            material = materials[k] if part is not None else _UNUSED
            data = material_textures(material, options.max_texture_size)
            bsdf = f"{key}.bsdf.nested_bsdf"
            for slot in ("base_color", "roughness", "metallic"):
                wanted[f"{bsdf}.{slot}.data"] = data[slot]
            wanted[f"{bsdf}.specular"] = data["specular"]
            wanted[f"{key}.bsdf.normalmap.data"] = data["normalmap"]
            if part is not None:
                jitter = jitters[k] if jitters is not None else None
                # plain floats: a UVTransform may hold NumPy values, whose == is elementwise
                jitter_key = None if jitter is None else (
                    float(jitter.scale), float(jitter.rotation), *(float(v) for v in jitter.offset)
                )
                refined = material.refinement
                refined_key = (refined.uv_scale, refined.uv_rotation) if refined is not None else None
                wanted[f"{key}.vertex_texcoords"] = (self._geometry, material.scale, jitter_key, refined_key)
        self._apply(wanted, parts, materials, jitters)
        self._shape_ref = weakref.ref(shape)
        return self.scene

    def _apply(
        self,
        wanted: dict[str, Any],
        parts: Sequence[PartMesh],
        materials: Sequence[MaterialSpec],
        jitters: Sequence[Any] | None,
    ) -> None:
        mi, dr, params, applied = self.mi, self.dr, self.params, self._applied
        moved = uploaded = False
        for name, value in wanted.items():
            marker = _marker(value)
            if name in applied and _same(applied[name], marker):
                continue
            if name == "sensor.to_world":
                params[name] = mi.ScalarTransform4f(value.tolist())
            elif name == "sensor.film.size":
                params[name] = mi.ScalarVector2u(value, value)
            elif name == "emitter.to_world":
                params[name] = mi.ScalarTransform4f().rotate([0, 1, 0], math.degrees(value[1]))
            elif name == "floor.vertex_positions":
                floor = _floor_part(value[1]) if value[0] == "floor" else _degenerate()
                self._set_mesh("floor", floor, uvs=floor.uvs)
            elif name == "floor.bsdf.reflectance.value":
                params[name] = dr.opaque(mi.Color3f, value)
            elif name.endswith(".geometry"):
                key = name.split(".", 1)[0]
                k = int(key.rsplit("_", 1)[-1])
                if value[0] == "part":
                    self._set_mesh(key, parts[k])  # its UVs follow (they need the material)
                else:
                    self._set_mesh(key, _degenerate(), uvs=np.zeros((3, 2), np.float32))
            elif name.endswith(".vertex_texcoords"):
                k = int(name.split(".", 1)[0].rsplit("_", 1)[-1])
                uvs = mitsuba_uvs(parts[k], materials[k], jitters[k] if jitters is not None else None)
                params[name] = mi.Float(aligned(uvs).ravel())
            elif isinstance(value, np.ndarray):
                params[name] = mi.TensorXf(aligned(value))
            else:  # scalars (envmap scale, specular): opaque, or each value would be a kernel literal
                params[name] = dr.opaque(mi.Float, value)
            applied[name] = marker
            moved |= name.endswith(".geometry") or name == "floor.vertex_positions"
            uploaded |= moved or name.endswith((".vertex_texcoords", ".data"))
        params.update()
        if uploaded:  # a replay would read the previous upload (module doc)
            self.invalidate()
        if moved:
            # Mitsuba 3.9 tells the envmap the scene's bounds before it recomputes them: without this,
            # its bounding sphere stays the previous shape's (too small: shadow rays stop short)
            for emitter in self.scene.emitters():
                emitter.set_scene(self.scene)

    def _set_mesh(self, key: str, part: PartMesh, uvs: np.ndarray | None = None) -> None:
        mi, params = self.mi, self.params
        params[f"{key}.vertex_positions"] = mi.Float(aligned(part.vertices).ravel())
        params[f"{key}.vertex_normals"] = mi.Float(aligned(part.normals).ravel())
        params[f"{key}.faces"] = mi.UInt32(aligned(part.faces, np.uint32).ravel())
        if uvs is not None:
            params[f"{key}.vertex_texcoords"] = mi.Float(aligned(uvs).ravel())


@lru_cache(maxsize=1)
def _frozen_render() -> Any:
    """`mi.render` under `dr.freeze`, keyed by `state` (version, film size, spp, seed): plain ints, so a
    new value re-traces (module doc)."""
    mi = ensure_mitsuba()
    import drjit as dr

    def render(scene: Any, state: tuple[int, int, int, int]) -> Any:
        return mi.render(scene, spp=state[2], seed=state[3])

    # a new configuration per material or shape is the design, not a misuse: no warning
    return dr.freeze(render, limit=FROZEN_CONFIGURATIONS, warn_after=1 << 30)


_POOLS: dict[tuple[str, int, tuple[int, int]], BeautyPool] = {}


def beauty_pool(parts: int, max_depth: int, envmap_resolution: tuple[int, int] = ENVMAP_RESOLUTION) -> BeautyPool:
    """The process's pool for this integrator depth and envmap resolution, grown to hold `parts` parts.

    Growing replaces the pool (the old one is freed first, so its registry ids are reused): one new
    kernel per growth step, never one per shape. Callers hold the render lock.
    """
    mi = ensure_mitsuba()
    key = (mi.variant(), int(max_depth), (int(envmap_resolution[0]), int(envmap_resolution[1])))
    pool = _POOLS.get(key)
    if pool is not None and pool.slots >= parts:
        return pool
    caster_slots()  # the exact passes' casters first: created later, they would change this kernel
    slots = slot_count(max(parts, pool.slots if pool is not None else 0))
    if pool is not None:
        del _POOLS[key]
        del pool
        gc.collect()
    _POOLS[key] = BeautyPool(slots, max_depth, envmap_resolution)
    return _POOLS[key]
