"""Mitsuba 3 scene XML of a PhotoShape that reloads (``mi.load_file``) and renders the same image.

The scene dict comes from the renderer's own `build_scene`, so the XML describes exactly what was
rendered. Mitsuba 3.9's dict -> XML path (``mi.parser.parse_dict`` + ``write_file``; older releases
had ``mi.xml.dict_to_xml``) cannot serialise in-memory objects (mitsuba-renderer/mitsuba3#982,
#598): it rejects ``mi.Mesh`` and ``mi.Bitmap`` values. So before converting:

- each part's ``mi.Mesh`` (its UVs already carry the texture-scale formula, the jitter and
  Mitsuba's v flip) is written with ``Mesh.write_ply`` and replaced by a ``ply`` shape with the
  part's BSDF dict (`render.scene.material_bsdf`);
- each ``mi.Bitmap`` (float32, resampled as rendered) is written as OpenEXR named by its texels
  (so a material used by several parts, and equal constant maps, are one file) and referenced by
  filename; sRGB-flagged ones are linearised first (EXR has no gamma flag; Mitsuba would otherwise
  read the encoded values as linear), so reloading gives the texels that were rendered;
- ``transform_relocate`` then copies every referenced file (PLYs, EXRs) into ``meshes/`` and
  ``textures/`` beside the XML, so the folder is self-contained and relocatable.

A refined material (`render.specs.Refinement`, `fit.refine`) needs nothing of its own here: its tint
and roughness scale are in the texels `material_bsdf` hands over (written to the EXRs), and its UV
scale and rotation in the PLYs' UVs, as the renderer bakes them. Why not a ``bitmap`` ``to_uv`` and
a scaled texture: Mitsuba 3 has no texture-multiply plugin, and ``to_uv`` would not turn the
normal map's tangent frame (see `render.scene`), so the XML would not render what publish rendered.

The scene is the one `Renderer.beauty` renders, not only the one `build_scene` describes: the
envmap is written as the renderer's persistent scene lights with it (resampled to
`render.pool.ENVMAP_RESOLUTION`; without an envmap, the pool's constant-radiance envmap rather than
a ``constant`` emitter, which draws other noise), and the sampler carries the render's `seed` as its
base seed. So the XML reloaded and rendered with Mitsuba's defaults (``mitsuba scene.xml``, or
``mi.render(mi.load_file(...))`` at seed 0) gives the image that it accompanies, noise included, when
`camera`, `size`, `spp` and `seed` are those of that render. The film size and sample count are XML
defaults (``$resx``/``$spp`` style parameters written by Mitsuba).
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photoshape_flow.export.pbr import ResolveRef, content_file_name
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.pool import envmap_data
from photoshape_flow.render.runtime import ensure_mitsuba
from photoshape_flow.render.scene import SceneOptions, build_scene, material_bsdf, part_key
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec, material_from_builtin


def concrete_materials(shape: Any, materials: Sequence[Any] | None, resolve_ref: ResolveRef | None) -> list[Any]:
    """Built-in parts (None) as MaterialSpecs, the way the renderer resolves them."""
    materials = list(materials) if materials is not None else [None] * len(shape.parts)
    out: list[MaterialSpec] = []
    for part, spec in zip(shape.parts, materials, strict=True):
        if spec is None:
            builtin = dict(part.builtin_material or {})
            builtin.setdefault("name", f"builtin_{part.name}")
            if resolve_ref is None:
                builtin.pop("texture", None)
            spec = material_from_builtin(builtin, resolve_ref or Path)
        out.append(spec)
    return out


def _write_exr(bitmap: Any, mi: Any, stage: Path) -> str:
    """Write a Bitmap as OpenEXR named by its texels (`pbr.content_file_name`): identical textures
    (a material on several parts, constant and flat maps) become one file; returns the path."""
    import numpy as np

    if bitmap.srgb_gamma():  # EXR is linear by definition: linearise, or the flag is lost
        bitmap = bitmap.convert(bitmap.pixel_format(), mi.Struct.Type.Float32, False)
    texels = np.asarray(bitmap)
    target = stage / content_file_name(repr(texels.shape).encode() + texels.tobytes(), "exr")
    if not target.exists():
        bitmap.write(str(target))
    return str(target)


def _serialisable(value: Any, mi: Any, stage: Path, written: dict[int, str]) -> Any:
    """Copy of a scene-dict value with Bitmaps written to content-named EXR files, each Bitmap object once."""
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for key, item in value.items():
            if key == "bitmap" and isinstance(item, mi.Bitmap):
                if id(item) not in written:
                    written[id(item)] = _write_exr(item, mi, stage)
                out["filename"] = written[id(item)]
            else:
                out[key] = _serialisable(item, mi, stage, written)
        return out
    if isinstance(value, mi.Object):
        raise TypeError(f"cannot write a {type(value).__name__} object to Mitsuba XML")
    return value


def rendered_envmap(envmap: EnvmapSpec | None) -> dict[str, Any]:
    """The envmap emitter as `Renderer.beauty` lights with it (`render.pool`): resampled data, same
    scale and rotation; radiance 1 everywhere when `envmap` is None."""
    import math


    mi = ensure_mitsuba()
    data = envmap_data(envmap)[:, 1:-1]  # without the plugin's wrap-around columns: it adds them again
    return {
        "type": "envmap",
        "bitmap": mi.Bitmap(data.copy()),
        "scale": float(envmap.scale) if envmap is not None else 1.0,
        "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], math.degrees(envmap.rotation if envmap else 0.0)),
    }


def scene_to_xml(scene: dict[str, Any], bsdfs: dict[str, dict[str, Any]], path: str | Path) -> Path:
    """Write a `build_scene` dict as XML + PLY meshes + EXR textures.

    `bsdfs`: part key -> the part's BSDF dict (the meshes in `scene` hold instantiated BSDFs).
    """
    mi = ensure_mitsuba()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="photoshape-xml-") as tmp:
        stage = Path(tmp)
        written: dict[int, str] = {}
        plain: dict[str, Any] = {}
        for key, value in scene.items():
            if isinstance(value, mi.Mesh):
                ply = stage / f"{key}.ply"
                value.write_ply(str(ply))
                entry: dict[str, Any] = {"type": "ply", "filename": str(ply)}
                if key in bsdfs:
                    entry["bsdf"] = _serialisable(bsdfs[key], mi, stage, written)
                plain[key] = entry
            else:
                plain[key] = _serialisable(value, mi, stage, written)
        config = mi.parser.ParserConfig(mi.variant())
        state = mi.parser.parse_dict(config, plain)
        mi.parser.transform_relocate(config, state, str(out.parent))
        mi.parser.write_file(state, str(out))
    return out


def write_mitsuba_xml(
    path: str | Path,
    shape: Any,
    materials: Sequence[Any] | None,
    envmap: EnvmapSpec | None,
    camera: Camera,
    *,
    uv_transforms: Sequence[Any] | None = None,
    size: int = 512,
    spp: int = 128,
    floor: bool = False,
    resolve_ref: ResolveRef | None = None,
    max_texture_size: int | None = None,
    seed: int = 0,
) -> Path:
    """Export the beauty scene of `shape` (built-ins resolved with `resolve_ref`) as Mitsuba XML.

    `max_texture_size` defaults to the renderer's (`SceneOptions`), so the XML holds the texels
    that the PhotoShape renders used; `seed` is the sampler's base seed (see the module docstring).
    """
    max_texture_size = max_texture_size or SceneOptions().max_texture_size
    specs = concrete_materials(shape, materials, resolve_ref)
    options = SceneOptions(
        size=size, spp=spp, mode="beauty", floor=floor, max_texture_size=max_texture_size,
        uv_transforms=tuple(uv_transforms) if uv_transforms is not None else None,
    )
    scene = build_scene(shape, specs, envmap, camera, options)
    scene["sensor"]["sampler"]["seed"] = int(seed)
    scene["emitter"] = rendered_envmap(envmap)
    bsdfs = {
        part_key(part.index): material_bsdf(spec, max_texture_size)
        for part, spec in zip(shape.parts, specs, strict=True)
        if len(part.faces)
    }
    return scene_to_xml(scene, bsdfs, path)
