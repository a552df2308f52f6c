"""Scenes as data: `build_scene` turns a shape, its materials, a light and a camera into a dict for
``mi.load_dict``.

Material mapping (one documented mapping for every material source):

- Every part gets the *same BSDF graph*: ``normalmap`` (OpenGL convention, raw) wrapping
  ``principled`` whose ``base_color``, ``roughness`` and ``metallic`` are ``bitmap`` textures.
  Absent maps become 2x2 constant bitmaps and an absent normal map a flat one (0.5, 0.5, 1).
  Why: Dr.Jit compiles one kernel per distinct BSDF code, so a uniform graph lets beauty renders
  of any material combination share one kernel (tests/render/test_beauty.py checks it), while a
  tiny texture fetch and a flat normal map cost next to nothing.
- ``albedo`` map: sRGB. It is decoded to linear once when the file is first loaded (cached), which
  is what the bitmap's ``raw=False`` would do on every scene load (13 ms per 512^2 map); so every
  bitmap is given to Mitsuba as linear data with ``raw=True``. ``roughness``/``metallic`` maps:
  linear data, reduced to one channel; normal maps: linear data. Analytic ``albedo`` is sRGB 0..1
  and converted to linear here; ``roughness``/``metallic`` are used as is (principled's roughness
  is the perceptual one, alpha = roughness^2, as in Disney/glTF sources).
- ``specular``: Mitsuba's principled takes a *scalar* specular (Fresnel 0..1, 0.5 = IOR 1.5), so a
  specular map contributes its mean value; analytic ``specular`` likewise; default 0.5.
- ``height``: ignored for rendering. Mitsuba has no displacement, and turning a height map into
  normals needs a world-space height scale the sources do not give; materials with a normal map
  (all MatSynth ones) already carry that detail.
- Textures larger than ``max_texture_size`` are downsampled on load (memory: Mitsuba keeps float32).

`Renderer.beauty` does not load these dicts: it rewrites one persistent scene (`pool.BeautyPool`) to
what `build_scene` describes, so that new shapes reuse the compiled kernel; `build_scene` stays the
reference description (tests compare both) and builds the AOV scenes.

UVs: `PartMesh.uvs` follow the OBJ/OpenGL convention (v = 0 at the image's bottom row). The
texture-scale formula and the `UVTransform` jitter (`specs.uv_matrix`) are baked into each part's
mesh UVs, and then v is flipped to Mitsuba's convention (v = 0 at the top row). Baking, rather than
the bitmap's ``to_uv``, keeps normal maps right under a rotation jitter: Mitsuba builds the
tangent frame of ``normalmap`` from the mesh's dp/du, which ``to_uv`` would not rotate.

Lighting: an ``envmap`` (lat-long, +y up) with ``scale`` and a rotation about +y, or a constant
white emitter when no envmap is given. The floor, when asked for, is a visible large diffuse
rectangle under the shape (Mitsuba has no shadow catcher; compositing shadows would cost a second
render). The camera is a ``perspective`` sensor with ``fov_axis = x`` and `Camera.to_world`.

AOV scenes (``mode="aov"``: the Mitsuba ``aov`` integrator route of ``Renderer.part_ids(...,
method="aov")``) contain the parts without materials or lights and sample pixel centres
(``stratified`` sampler without jitter, box filter, 1 spp), so every pixel holds the value of
exactly one ray: an exact part ID, never a blend at edges. The default exact passes use
`raycast.RayCaster` with the same pixel-centre rays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from photoshape_flow.geometry.mesh import PartMesh, ShapeMesh
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.runtime import ensure_mitsuba
from photoshape_flow.render.specs import (
    EnvmapSpec,
    MaterialSpec,
    UVTransform,
    apply_uv_matrix,
    refined_uv_matrix,
    srgb_to_linear,
)
from photoshape_flow.render.texture_cache import TEXTURE_CACHE_BYTES, ByteLRU

AOV_CHANNELS: dict[str, tuple[str, int]] = {
    # name -> (Mitsuba AOV type, channels)
    "shape_index": ("shape_index", 1),
    "depth": ("depth", 1),
    "normal": ("sh_normal", 3),
    "position": ("position", 3),
}
DEFAULTS = {"albedo": (0.8, 0.8, 0.8), "roughness": 0.5, "metallic": 0.0, "specular": 0.5}


@dataclass(frozen=True)
class SceneOptions:
    """How to render: the film, the integrator and extras of the scene."""

    size: int = 256
    spp: int = 64
    mode: Literal["beauty", "aov"] = "beauty"
    aovs: tuple[str, ...] = ("shape_index",)
    max_depth: int = 8
    floor: bool = False
    floor_albedo: float = 0.8
    uv_transforms: tuple[UVTransform | None, ...] | None = None
    max_texture_size: int = 1024


def part_key(index: int) -> str:
    """Scene-dict key (and Mitsuba shape id) of part `index`."""
    return f"part_{index:04d}"


def part_index_from_key(key: str) -> int:
    return int(key.rsplit("_", 1)[-1])


def mitsuba_uvs(part: PartMesh, material: MaterialSpec | None, jitter: UVTransform | None) -> np.ndarray:
    """The UVs Mitsuba gets for `part`: the texture-scale formula, jitter and refinement, then v flipped."""
    matrix = refined_uv_matrix(part.uv_density, material, jitter)
    uvs = apply_uv_matrix(part.uvs, matrix)
    uvs[:, 1] = 1.0 - uvs[:, 1]
    return uvs


def aligned(values: Any, dtype: Any = np.float32, alignment: int = 64) -> np.ndarray:
    """`values` as a C-contiguous array whose data starts on a 64-byte boundary (a copy if needed).

    Why: Dr.Jit wraps NumPy memory and uses packet (vector) gathers only from 64-byte aligned
    buffers, so without this the traced code, and thus the kernel cache key, depends on where NumPy
    happened to allocate (measured: the path tracer compiled again for a mesh whose UVs moved).
    """
    array = np.asarray(values, dtype)
    if array.flags.c_contiguous and array.ctypes.data % alignment == 0:
        return array
    raw = np.empty(array.nbytes + alignment, np.uint8)
    start = (-raw.ctypes.data) % alignment
    out = raw[start : start + array.nbytes].view(array.dtype).reshape(array.shape)
    out[...] = array
    return out


def make_mesh(
    key: str, part: PartMesh, uvs: np.ndarray | None = None, bsdf: Any = None
) -> Any:
    """A Mitsuba mesh built from the part's numpy arrays (normals always, UVs when given)."""
    mi = ensure_mitsuba()
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf
    vertices = aligned(part.vertices)
    faces = aligned(part.faces, np.uint32)
    mesh = mi.Mesh(
        key, len(vertices), len(faces), props=props, has_vertex_normals=True, has_vertex_texcoords=uvs is not None
    )
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(vertices.ravel())
    params["faces"] = mi.UInt32(faces.ravel())
    params["vertex_normals"] = mi.Float(aligned(part.normals).ravel())
    if uvs is not None:
        params["vertex_texcoords"] = mi.Float(aligned(uvs).ravel())
    params.update()
    return mesh


TEXTURES = ByteLRU(TEXTURE_CACHE_BYTES)  # decoded maps by (path, mtime, kind, size cap)


def _load_texture(path: str, kind: str, max_size: int) -> np.ndarray:
    """Load a texture as linear float32 (H, W, C): RGB for colour/normal, 1 channel for scalars."""
    mi = ensure_mitsuba()
    try:
        bitmap = mi.Bitmap(path)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read texture ({exc})") from exc
    if kind != "albedo":
        # data maps: the stored numbers are the values; without this, convert() would linearise
        # 8-bit files that Mitsuba flags as sRGB
        bitmap.set_srgb_gamma(False)
    fmt = mi.Bitmap.PixelFormat.Y if kind == "scalar" else mi.Bitmap.PixelFormat.RGB
    # albedo: sRGB-flagged files are decoded to linear here, once (what raw=False does on every load)
    bitmap = bitmap.convert(fmt, mi.Struct.Type.Float32, False)
    width, height = bitmap.size()
    if max(width, height) > max_size > 0:
        factor = max_size / max(width, height)
        bitmap = bitmap.resample([max(1, round(width * factor)), max(1, round(height * factor))])
    array = np.array(bitmap, dtype=np.float32, copy=True)
    return aligned(array.reshape(array.shape[0], array.shape[1], -1))


def texture_array(path: Path, kind: Literal["albedo", "scalar", "normal"], max_size: int) -> np.ndarray:
    """Linear float32 (H, W, C) texture of a material map (cached by path, mtime, kind and size cap: an
    edited file is reloaded)."""
    path = Path(path)
    try:
        mtime = path.stat().st_mtime_ns
    except OSError as exc:
        raise ValueError(f"{path}: texture file missing ({exc.strerror})") from exc
    return TEXTURES.get_or_load((str(path), mtime, kind, max_size), lambda: _load_texture(str(path), kind, max_size))


def _constant(value: Sequence[float] | float) -> np.ndarray:
    """A 2x2 constant texture (Mitsuba pads 1x1 bitmaps to 2x2 anyway)."""
    values = np.asarray(value, np.float32).reshape(1, 1, -1)
    return aligned(np.broadcast_to(values, (2, 2, values.shape[2])))


def material_textures(material: MaterialSpec, max_texture_size: int = 1024) -> dict[str, Any]:
    """The data behind a material's BSDF: linear float32 textures by principled slot, and ``specular``.

    Keys: ``base_color`` (H, W, 3), ``roughness`` (H, W, 1), ``metallic`` (H, W, 1), ``normalmap``
    (H, W, 3; flat when the material has none) and the scalar ``specular``.
    """
    maps, params = material.maps, material.params
    out: dict[str, Any] = {}
    if "albedo" in maps:
        out["base_color"] = texture_array(maps["albedo"], "albedo", max_texture_size)
    else:
        albedo = params.get("albedo", DEFAULTS["albedo"])
        if isinstance(albedo, (int, float)):
            albedo = [albedo] * 3
        if len(albedo) != 3:
            raise ValueError(f"material {material.name}: albedo needs 3 values, got {albedo!r}")
        out["base_color"] = _constant(srgb_to_linear(albedo))
    for channel in ("roughness", "metallic"):
        if channel in maps:
            out[channel] = texture_array(maps[channel], "scalar", max_texture_size)
        else:
            out[channel] = _constant([float(np.clip(float(params.get(channel, DEFAULTS[channel])), 0.0, 1.0))])
    if "normal" in maps:
        out["normalmap"] = texture_array(maps["normal"], "normal", max_texture_size)
    else:
        out["normalmap"] = _constant([0.5, 0.5, 1.0])
    if "specular" in maps:
        specular = float(np.mean(texture_array(maps["specular"], "scalar", max_texture_size)))
    else:
        specular = float(params.get("specular", DEFAULTS["specular"]))
    out["specular"] = float(np.clip(specular, 0.0, 1.0))
    if material.refinement is not None:
        out.update(refined_textures(out["base_color"], out["roughness"], material.refinement))
    return out


def refined_textures(base_color: np.ndarray, roughness: np.ndarray, refinement: Any) -> dict[str, np.ndarray]:
    """The base colour times the tint and the roughness times its scale, each clipped to 0..1 (`Refinement`)."""
    tint = np.asarray(refinement.tint, np.float32).reshape(1, 1, 3)
    return {"base_color": aligned(np.clip(base_color * tint, 0.0, 1.0)),
            "roughness": aligned(np.clip(roughness * np.float32(refinement.roughness_scale), 0.0, 1.0))}


def _bitmap(array: np.ndarray) -> dict[str, Any]:
    mi = ensure_mitsuba()
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(array)), "raw": True}


def material_bsdf(material: MaterialSpec, max_texture_size: int = 1024) -> dict[str, Any]:
    """The BSDF dict of a material (see the module docstring for the mapping)."""
    data = material_textures(material, max_texture_size)
    principled = {
        "type": "principled",
        "base_color": _bitmap(data["base_color"]),
        "roughness": _bitmap(data["roughness"]),
        "metallic": _bitmap(data["metallic"]),
        "specular": data["specular"],
    }
    return {"type": "normalmap", "normalmap": _bitmap(data["normalmap"]), "bsdf": principled}


def envmap_emitter(envmap: EnvmapSpec | None) -> dict[str, Any]:
    """An ``envmap`` emitter (scaled, rotated about +y) or a constant white sky when None."""
    if envmap is None:
        return {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
    mi = ensure_mitsuba()
    if not Path(envmap.path).is_file():
        raise ValueError(f"{envmap.path}: environment map file missing")
    return {
        "type": "envmap",
        "filename": str(envmap.path),
        "scale": float(envmap.scale),
        "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], math.degrees(envmap.rotation)),
    }


def sensor_dict(camera: Camera, options: SceneOptions) -> dict[str, Any]:
    mi = ensure_mitsuba()
    if options.mode == "aov":
        sampler = {"type": "stratified", "sample_count": 1, "jitter": False}
        film = {"type": "hdrfilm", "width": options.size, "height": options.size, "rfilter": {"type": "box"}}
    else:
        sampler = {"type": "independent", "sample_count": options.spp}
        film = {"type": "hdrfilm", "width": options.size, "height": options.size, "pixel_format": "rgba"}
    return {
        "type": "perspective",
        "fov": float(camera.fov),
        "fov_axis": "x",
        "to_world": mi.ScalarTransform4f(camera.to_world().tolist()),
        "sampler": sampler,
        "film": film,
    }


def floor_shape(shape: ShapeMesh, albedo: float) -> dict[str, Any]:
    mi = ensure_mitsuba()
    y = float(shape.bounds()[0][1]) - 1e-4
    to_world = mi.ScalarTransform4f().translate([0, y, 0]).rotate([1, 0, 0], -90).scale([20, 20, 1])
    reflectance = {"type": "rgb", "value": [albedo] * 3}
    return {"type": "rectangle", "to_world": to_world, "bsdf": {"type": "diffuse", "reflectance": reflectance}}


def build_scene(
    shape: ShapeMesh,
    materials: Sequence[MaterialSpec | None] | None,
    envmap: EnvmapSpec | None,
    camera: Camera,
    options: SceneOptions,
) -> dict[str, Any]:
    """The ``mi.load_dict`` description of one render.

    `materials[i]` belongs to `shape.parts[i]` and must be concrete in ``beauty`` mode (the
    renderer resolves built-in ones first); AOV scenes ignore materials and lights. Parts without
    faces are left out.
    """
    mi = ensure_mitsuba()
    if options.mode == "aov":
        aovs = ",".join(f"{name}:{AOV_CHANNELS[name][0]}" for name in options.aovs)
        integrator: dict[str, Any] = {"type": "aov", "aovs": aovs}
    else:
        integrator = {"type": "path", "max_depth": int(options.max_depth), "hide_emitters": True}
    scene: dict[str, Any] = {"type": "scene", "integrator": integrator, "sensor": sensor_dict(camera, options)}
    if options.mode == "beauty":
        if materials is None or len(materials) != len(shape.parts):
            raise ValueError(
                f"need one material per part: {len(shape.parts)} parts, "
                f"{'no' if materials is None else len(materials)} materials"
            )
        scene["emitter"] = envmap_emitter(envmap)
        if options.floor:
            scene["floor"] = floor_shape(shape, options.floor_albedo)
    jitters = options.uv_transforms
    if jitters is not None and len(jitters) != len(shape.parts):
        raise ValueError(f"need one UV transform per part: {len(shape.parts)} parts, {len(jitters)} transforms")
    for i, part in enumerate(shape.parts):
        if len(part.faces) == 0:
            continue
        key = part_key(part.index)
        if options.mode == "aov":
            scene[key] = make_mesh(key, part)
            continue
        material = materials[i]  # type: ignore[index]
        if material is None:
            raise ValueError(f"part {part.index} ({part.name}): no material (resolve built-ins first)")
        bsdf = mi.load_dict(material_bsdf(material, options.max_texture_size))
        uvs = mitsuba_uvs(part, material, jitters[i] if jitters is not None else None)
        scene[key] = make_mesh(key, part, uvs=uvs, bsdf=bsdf)
    return scene
