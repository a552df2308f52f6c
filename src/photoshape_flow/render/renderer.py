"""The Renderer: beauty renders, exact part-ID maps and fast viewpoint sweeps with Mitsuba 3.

Beauty renders use the path tracer on one persistent scene per process (`pool.BeautyPool`: a fixed
number of part slots, a floor, an envmap and a sensor) whose parameters are rewritten for every
render (meshes, UVs, textures, envmap, camera); the scene is what `scene.build_scene` describes.
Why: Dr.Jit's kernels embed the registry ids of every live BSDF/shape/emitter instance, so loading a
scene per shape compiled a new path-tracing kernel per shape (~0.4 s against ~0.05 s for a 96 px,
16 spp render). With the pool, a process compiles one per pool size (4, 8, 16, ... slots) and film
size. Other Mitsuba objects created or freed between renders change the kernel too, which is why
the exact passes below also use persistent casters (`raycast.caster_for`); the AOV route
(``method="aov"``, cross-checks only) still loads scenes and costs one recompilation when it does.

Part IDs, silhouettes, depth, normals and the grey shading for HOG come from `raycast.RayCaster`:
pixel-centre rays for a batch of cameras in one kernel against the shape as one merged mesh, part
ID = ``face_part[prim_index]``. Three routes give identical maps; bench/render.py measures them:
(1) Mitsuba's ``aov`` integrator with ``shape_index`` (1 spp, pixel-centre ``stratified`` sampler,
box filter), one ``mi.render`` per view with the sensor moved through ``mi.traverse``, ids mapped
through ``dr.reinterpret_array(mi.UInt32, scene.shapes_dr())`` (they are Dr.Jit registry ids);
(2) per-part constant albedos decoded from the ``albedo`` AOV (needs a second BSDF set, caps ids at
what a colour channel encodes); (3) the batched ray caster, 5-8x faster than (1) and (2) because
per-render launch/readback overhead dominates small AOV images. So (3) is the default and (1)
stays available as ``part_ids(..., method="aov")`` for cross-checks.

Meshes are cached per shape *object* (weak reference): a shape mutated in place after its first
render is not noticed. Renders are serialised by a process-wide lock (Dr.Jit's state is global),
so a Renderer may be shared by threads but renders one image at a time. Needs a JIT variant
(``llvm_*``, or ``cuda_*`` on a GPU machine).
"""

from __future__ import annotations

import threading
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.pool import ENVMAP_RESOLUTION, BeautyPool, beauty_pool
from photoshape_flow.render.raycast import RayCaster, caster_for
from photoshape_flow.render.runtime import ensure_mitsuba
from photoshape_flow.render.scene import SceneOptions, build_scene, part_index_from_key
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec, UVTransform, material_from_builtin
from photoshape_flow.render.tonemap import composite, saturated_fraction
from photoshape_flow.store import default_store

_RENDER_LOCK = threading.RLock()


@dataclass
class BeautyResult:
    """A path-traced render: display image, linear radiance and coverage."""

    srgb: np.ndarray  # (H, W, 3) uint8
    hdr: np.ndarray  # (H, W, 3) float32, linear, composited over the background (0 when transparent)
    alpha: np.ndarray  # (H, W) float32 coverage of shape (and floor)
    saturated_fraction: float = 0.0
    seconds: float = 0.0


@dataclass
class SweepResult:
    """Part-ID maps (and optional grey shaded images) of one shape from many cameras."""

    part_ids: np.ndarray  # (N, H, W) uint16, 0 = background
    shaded: np.ndarray | None  # (N, H, W) float32 grey headlight shading, background 1 (white)
    seconds: float = 0.0

    @property
    def masks(self) -> np.ndarray:
        return self.part_ids > 0


@dataclass
class _AovScene:
    scene: Any
    sensor: Any
    params: Any
    lut: np.ndarray  # registry id -> part index
    shape_ref: weakref.ref
    camera: Camera | None = None


class Renderer:
    """Mitsuba renders of ShapeMesh objects (see contributing.md, "Rendering API").

    `resolve` maps a built-in texture's blob ref to a path (default: the configured blob store).
    `envmap_resolution` (height, width): every envmap is resampled to it (see `pool`).
    """

    def __init__(
        self,
        *,
        variant: str | None = None,
        threads: int | None = None,
        resolve: Callable[[str], Path] | None = None,
        max_depth: int = 8,
        max_texture_size: int = 1024,
        cache_size: int = 4,
        envmap_resolution: tuple[int, int] = ENVMAP_RESOLUTION,
    ):
        self.mi = ensure_mitsuba(variant, threads)
        import drjit as dr

        if self.mi.variant().startswith("scalar"):
            raise ValueError(f"the Renderer needs a JIT variant (llvm_ad_rgb), not {self.mi.variant()!r}")

        self.dr = dr
        self._resolve = resolve
        self.max_depth = max_depth
        self.max_texture_size = max_texture_size
        self.envmap_resolution = (int(envmap_resolution[0]), int(envmap_resolution[1]))
        self._aov_cache: OrderedDict[tuple[int, int], _AovScene] = OrderedDict()
        self._cache_size = cache_size

    # -- materials -------------------------------------------------------------------------
    def resolve_ref(self, ref: str) -> Path:
        if self._resolve is None:
            self._resolve = default_store().resolve
        return Path(self._resolve(ref))

    def resolve_materials(
        self, shape: ShapeMesh, materials: Sequence[MaterialSpec | None] | None
    ) -> list[MaterialSpec]:
        """One concrete material per part; None (or no list) means the part's built-in material."""
        if materials is None:
            materials = [None] * len(shape.parts)
        if len(materials) != len(shape.parts):
            raise ValueError(f"need one material per part: {len(shape.parts)} parts, {len(materials)} materials")
        return [
            m if m is not None else material_from_builtin(p.builtin_material, self.resolve_ref)
            for m, p in zip(materials, shape.parts, strict=True)
        ]

    # -- beauty ----------------------------------------------------------------------------
    def beauty(
        self,
        shape: ShapeMesh,
        materials: Sequence[MaterialSpec | None] | None,
        camera: Camera,
        envmap: EnvmapSpec | None,
        *,
        size: int = 256,
        spp: int = 64,
        uv_transforms: Sequence[UVTransform | None] | None = None,
        background: Literal["white", "transparent"] = "white",
        floor: bool = False,
        seed: int = 0,
        record: bool = True,
    ) -> BeautyResult:
        """Path-traced image under the envmap (constant white sky when `envmap` is None).

        `record`: freeze the render for replays of this configuration (`BeautyPool.render`); False
        for callers whose renders never repeat a configuration and seed.
        """
        if background not in ("white", "transparent"):
            raise ValueError(f"background must be 'white' or 'transparent', got {background!r}")
        start = time.perf_counter()
        options = SceneOptions(
            size=size,
            spp=spp,
            mode="beauty",
            max_depth=self.max_depth,
            floor=floor,
            uv_transforms=tuple(uv_transforms) if uv_transforms is not None else None,
            max_texture_size=self.max_texture_size,
        )
        resolved = self.resolve_materials(shape, materials)
        with _RENDER_LOCK:
            image = self._beauty_pool(shape, resolved, envmap, camera, options).render(spp, seed, record)
        premultiplied, alpha = image[..., :3], image[..., 3]
        hdr, srgb = composite(premultiplied, alpha, background)
        return BeautyResult(
            srgb=srgb,
            hdr=hdr,
            alpha=np.clip(alpha, 0.0, 1.0).astype(np.float32),
            saturated_fraction=saturated_fraction(premultiplied, alpha),
            seconds=time.perf_counter() - start,
        )

    def _beauty_pool(
        self,
        shape: ShapeMesh,
        materials: list[MaterialSpec],
        envmap: EnvmapSpec | None,
        camera: Camera,
        options: SceneOptions,
    ) -> BeautyPool:
        """The process's beauty pool (grown to the shape's part count) set up for this render."""
        pool = beauty_pool(len(shape.parts), options.max_depth, self.envmap_resolution)
        pool.prepare(shape, materials, envmap, camera, options)
        return pool

    # -- exact passes ----------------------------------------------------------------------
    def _caster(self, shape: ShapeMesh) -> RayCaster:
        return caster_for(shape)

    def passes(
        self,
        shape: ShapeMesh,
        camera: Camera,
        size: int = 256,
        *,
        normals: bool = False,
        depth: bool = False,
        shaded: bool = False,
    ) -> dict[str, np.ndarray]:
        """Exact per-pixel passes from one camera (pixel-centre rays).

        ``part_ids`` (H, W) uint16 and ``mask`` (H, W) bool always; ``normals`` (H, W, 3) float32
        world-space shading normals as the mesh has them (not flipped towards the camera; 0 on
        background), ``depth`` (H, W) float32 distance along the
        viewing axis as `Camera.project` reports it (0 on background), ``shaded`` (H, W) float32
        grey headlight shading (background 1) when asked for.
        """
        with _RENDER_LOCK:
            out = self._caster(shape).cast([camera], size, normals=normals, depth=depth, shaded=shaded)
        result = {name: array[0] for name, array in out.items()}
        result["mask"] = result["part_ids"] > 0
        return result

    def part_ids(self, shape: ShapeMesh, camera: Camera, size: int = 256, *, method: str = "rays") -> np.ndarray:
        """(H, W) uint16 map: 0 = background, else `PartMesh.index` of the part hit at the pixel centre.

        ``method="aov"`` renders it with Mitsuba's ``aov`` integrator (``shape_index``) instead of
        the batched ray caster; both give the same map (kept for cross-checks and the benchmark).
        """
        if method == "aov":
            with _RENDER_LOCK:
                return self._aov_part_ids(shape, camera, size)
        if method != "rays":
            raise ValueError(f"method must be 'rays' or 'aov', got {method!r}")
        return self.passes(shape, camera, size)["part_ids"]

    def silhouette(self, shape: ShapeMesh, camera: Camera, size: int = 256) -> np.ndarray:
        """(H, W) bool mask of the shape."""
        return self.passes(shape, camera, size)["mask"]

    def sweep(self, shape: ShapeMesh, cameras: Sequence[Camera], size: int = 100, shaded: bool = True) -> SweepResult:
        """Part-ID maps (and grey headlight-shaded images for HOG) of one shape from many cameras.

        The scene is built once per shape and all views are cast in a few batched launches, so no
        kernel is recompiled per view or per shape. Part IDs equal `part_ids` for the same camera.
        """
        start = time.perf_counter()
        with _RENDER_LOCK:
            out = self._caster(shape).cast(list(cameras), size, shaded=shaded)
        return SweepResult(part_ids=out["part_ids"], shaded=out.get("shaded"), seconds=time.perf_counter() - start)

    # -- Mitsuba aov-integrator route (cross-check and benchmark) ---------------------------
    def _aov_scene(self, shape: ShapeMesh, size: int) -> _AovScene:
        key = (id(shape), int(size))
        cached = self._aov_cache.get(key)
        if cached is not None and cached.shape_ref() is shape:
            self._aov_cache.move_to_end(key)
            return cached
        mi, dr = self.mi, self.dr
        options = SceneOptions(size=int(size), mode="aov", aovs=("shape_index",))
        scene = mi.load_dict(build_scene(shape, None, None, Camera(0.0, 0.0), options))
        # In LLVM variants the AOV holds each shape's Dr.Jit registry id, not its position.
        registry = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64)
        lut = np.zeros(int(registry.max(initial=0)) + 1, np.uint16)
        for reg, mesh in zip(registry, scene.shapes(), strict=True):
            lut[reg] = part_index_from_key(mesh.id())
        sensor = scene.sensors()[0]
        entry = _AovScene(scene, sensor, mi.traverse(sensor), lut, weakref.ref(shape))
        self._aov_cache[key] = entry
        while len(self._aov_cache) > self._cache_size:
            self._aov_cache.popitem(last=False)
        return entry

    def _aov_part_ids(self, shape: ShapeMesh, camera: Camera, size: int) -> np.ndarray:
        entry = self._aov_scene(shape, size)
        if entry.camera != camera:
            entry.params["to_world"] = self.mi.ScalarTransform4f(camera.to_world().tolist())
            entry.params["x_fov"] = float(camera.fov)
            entry.params.update()
            entry.camera = camera
        image = np.array(self.mi.render(entry.scene, sensor=entry.sensor, spp=1, seed=0), dtype=np.float32)
        raw = (image[..., 0] if image.ndim == 3 else image).astype(np.int64)
        lut = entry.lut
        inside = (raw >= 0) & (raw < len(lut))
        return np.where(inside, lut[np.clip(raw, 0, len(lut) - 1)], 0).astype(np.uint16)
