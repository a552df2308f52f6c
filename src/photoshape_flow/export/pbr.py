"""Materials as the interchange formats want them: metallic-roughness PBR with encoded texture images.

Every exporter (glTF, OBJ) reads a `PbrMaterial`, so all of them agree on one conversion:

- base colour: the `albedo` map (sRGB, 8-bit RGB) times a factor of 1, or the analytic/built-in
  albedo converted from sRGB to a *linear* factor (glTF's `baseColorFactor` is linear);
- ORM: one linear RGB image, R = ambient occlusion (1: the material set has none), G = roughness,
  B = metallic; a channel without a map is filled with the material's constant so the factors stay 1;
- normal: the OpenGL-convention (+Y green) tangent-space map as stored (glTF uses OpenGL too);
- specular and height have no core glTF slot; they are listed in `extra_maps` for OBJ and the sidecar;
- a `Refinement` (`fit.refine`) multiplies the base colour factor by its tint and the roughness factor
  by its scale, clipped to 0..1 as the renderer clips them; where a factor cannot hold it (a tint
  above 1 on a texture, a roughness scale above 1 on a map: glTF factors stop at 1) it is baked
  into that texture instead, so every viewer shows what was rendered. Its UV scale and rotation are
  kept in `uv_transform` for the formats that carry one (glTF's KHR_texture_transform).

Materials come as `photoshape_flow.render.MaterialSpec` (read by attribute, so any object with `name`,
`substance`, `maps`, `params` and `scale` works) or `None` for a part's built-in material, whose
texture is a blob ref that the caller resolves with `resolve_ref`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.render.specs import linear_to_srgb, material_from_builtin, srgb_to_linear

ResolveRef = Callable[[str], Path]

DEFAULT_ROUGHNESS = 0.5
DEFAULT_METALLIC = 0.0


def content_file_name(data: bytes, ext: str) -> str:
    """A file name given by the bytes (``<sha256 prefix>.<ext>``): writers that share one texture
    folder (`export.bundle`) write identical textures once, whichever format or material wrote them."""
    return f"{hashlib.sha256(data).hexdigest()[:16]}.{ext}"


@dataclass(frozen=True)
class EncodedImage:
    """An image file's bytes, ready to embed or write (PNG or JPEG, 8-bit)."""

    data: bytes
    mime: str

    @property
    def ext(self) -> str:
        return "jpg" if self.mime == "image/jpeg" else "png"

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.data).hexdigest()


@dataclass
class PbrMaterial:
    """One exported material in metallic-roughness form."""

    name: str
    base_color_factor: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)  # linear RGBA
    roughness_factor: float = DEFAULT_ROUGHNESS
    metallic_factor: float = DEFAULT_METALLIC
    base_color: EncodedImage | None = None
    orm: EncodedImage | None = None
    normal: EncodedImage | None = None
    roughness: EncodedImage | None = None  # single-channel copies of the source maps (OBJ's map_Pr /
    metallic: EncodedImage | None = None  # map_Pm); None where the ORM channel is a constant
    extra_maps: dict[str, Path] = field(default_factory=dict)
    substance: str | None = None
    scale: float | None = None
    builtin: bool = False
    uv_transform: tuple[float, float] | None = None  # the refinement's (uv scale, uv rotation radians)
    refinement: dict[str, Any] | None = None  # `Refinement.to_dict()`, for the formats' metadata


def _read(path: Path) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    if image.ndim == 3 and image.shape[2] >= 3:
        image = image[..., [2, 1, 0, *range(3, image.shape[2])]]
    return image


def _to_unit_float(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image.astype(np.float32) / 255.0
    if image.dtype == np.uint16:
        return image.astype(np.float32) / 65535.0
    return np.clip(image.astype(np.float32), 0.0, 1.0)


def _to_u8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(_to_unit_float(image) * 255.0), 0, 255).astype(np.uint8)


def _rgb(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return np.repeat(image[..., None], 3, axis=2)
    if image.shape[2] == 1:
        return np.repeat(image, 3, axis=2)
    return image[..., :3]


def _gray(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else image[..., 0]


def _limit(image: np.ndarray, max_size: int | None) -> np.ndarray:
    import cv2

    if not max_size or max(image.shape[:2]) <= max_size:
        return image
    h, w = image.shape[:2]
    f = max_size / max(h, w)
    return cv2.resize(image, (max(1, round(w * f)), max(1, round(h * f))), interpolation=cv2.INTER_AREA)


def encode_png(image: np.ndarray) -> EncodedImage:
    """8-bit gray/RGB/RGBA array -> PNG bytes (deterministic for equal pixels)."""
    import cv2

    array = np.ascontiguousarray(image)
    if array.ndim == 3 and array.shape[2] >= 3:
        array = array[..., [2, 1, 0, *range(3, array.shape[2])]]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(array))
    if not ok:
        raise ValueError(f"could not encode an image of shape {image.shape} as PNG")
    return EncodedImage(buf.tobytes(), "image/png")


def _color_image(path: Path, max_size: int | None) -> EncodedImage:
    """An 8-bit RGB texture; PNG/JPEG files already in that form are passed through byte for byte."""
    head = path.read_bytes()[:4]
    is_png, is_jpeg = head == b"\x89PNG", head[:3] == b"\xff\xd8\xff"
    image = _read(path)
    if (is_png or is_jpeg) and image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3 and (
        not max_size or max(image.shape[:2]) <= max_size
    ):
        return EncodedImage(path.read_bytes(), "image/png" if is_png else "image/jpeg")
    return encode_png(_limit(_rgb(_to_u8(image)), max_size))


def _constant(params: Mapping[str, Any], key: str, default: float) -> float:
    value = params.get(key, default)
    try:
        return float(value)
    except (TypeError, ValueError):
        return default


def pbr_from_spec(spec: Any, *, max_texture_size: int | None = None) -> PbrMaterial:
    """A MaterialSpec (SVBRDF maps or analytic constants) in metallic-roughness form."""
    maps = {str(k): Path(v) for k, v in dict(getattr(spec, "maps", None) or {}).items()}
    params = dict(getattr(spec, "params", None) or {})
    albedo = params.get("albedo", [0.8, 0.8, 0.8])
    roughness = _constant(params, "roughness", DEFAULT_ROUGHNESS)
    metallic = _constant(params, "metallic", DEFAULT_METALLIC)
    out = PbrMaterial(
        name=str(spec.name),
        substance=getattr(spec, "substance", None),
        scale=getattr(spec, "scale", None),
        roughness_factor=roughness,
        metallic_factor=metallic,
    )
    if "albedo" in maps:
        out.base_color = _color_image(maps["albedo"], max_texture_size)
        out.base_color_factor = (1.0, 1.0, 1.0, 1.0)
    else:
        lin = srgb_to_linear(albedo[:3])
        out.base_color_factor = (float(lin[0]), float(lin[1]), float(lin[2]), 1.0)
    if "normal" in maps:
        out.normal = encode_png(_limit(_rgb(_to_u8(_read(maps["normal"]))), max_texture_size))
    rough_map = _gray(_to_u8(_read(maps["roughness"]))) if "roughness" in maps else None
    metal_map = _gray(_to_u8(_read(maps["metallic"]))) if "metallic" in maps else None
    if rough_map is not None or metal_map is not None:
        out.orm, out.roughness, out.metallic = _pack_orm(rough_map, metal_map, roughness, metallic, max_texture_size)
        out.roughness_factor = 1.0
        out.metallic_factor = 1.0
    out.extra_maps = {k: v for k, v in maps.items() if k in ("specular", "height")}
    refinement = getattr(spec, "refinement", None)
    if refinement is not None:
        refine_pbr(out, refinement)
    return out


def refine_pbr(mat: PbrMaterial, refinement: Any) -> None:
    """Apply a `render.specs.Refinement` to a converted material in place (see the module docstring)."""
    tint = np.asarray(refinement.tint, np.float64)
    if mat.base_color is not None and tint.max() > 1.0:
        mat.base_color = encode_png(_tinted_srgb(_decode(mat.base_color), tint))
    else:
        factor = np.clip(np.asarray(mat.base_color_factor[:3], np.float64) * tint, 0.0, 1.0)
        mat.base_color_factor = (float(factor[0]), float(factor[1]), float(factor[2]), mat.base_color_factor[3])
    scale = float(refinement.roughness_scale)
    if mat.orm is not None and scale > 1.0:
        orm = _decode(mat.orm)
        orm[..., 1] = np.clip(np.rint(orm[..., 1].astype(np.float64) * scale), 0, 255).astype(np.uint8)
        mat.orm = encode_png(orm)
        if mat.roughness is not None:
            mat.roughness = encode_png(orm[..., 1])
    else:
        mat.roughness_factor = float(np.clip(mat.roughness_factor * scale, 0.0, 1.0))
    if refinement.uv_scale != 1.0 or refinement.uv_rotation != 0.0:
        mat.uv_transform = (float(refinement.uv_scale), float(refinement.uv_rotation))
    mat.refinement = refinement.to_dict()


def _decode(image: EncodedImage) -> np.ndarray:
    """An encoded 8-bit image back to an RGB array."""
    import cv2

    array = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_COLOR)
    if array is None:
        raise ValueError("could not decode a texture")
    return np.ascontiguousarray(array[..., ::-1])


def _tinted_srgb(srgb: np.ndarray, tint: np.ndarray) -> np.ndarray:
    """An sRGB 8-bit image times a linear tint, clipped, back in sRGB 8-bit (as the renderer tints)."""
    linear = srgb_to_linear(srgb.astype(np.float64) / 255.0) * tint.reshape(1, 1, 3)
    return np.clip(np.rint(linear_to_srgb(np.clip(linear, 0.0, 1.0)) * 255.0), 0, 255).astype(np.uint8)


def _pack_orm(
    rough: np.ndarray | None, metal: np.ndarray | None, roughness: float, metallic: float, max_size: int | None
) -> tuple[EncodedImage, EncodedImage | None, EncodedImage | None]:
    import cv2

    shapes = [m.shape[:2] for m in (rough, metal) if m is not None]
    h, w = max(shapes, key=lambda s: s[0] * s[1])

    def fit(channel: np.ndarray | None, constant: float) -> np.ndarray:
        if channel is None:
            return np.full((h, w), round(constant * 255), np.uint8)
        if channel.shape[:2] != (h, w):
            channel = cv2.resize(channel, (w, h), interpolation=cv2.INTER_LINEAR)
        return channel

    g, b = fit(rough, roughness), fit(metal, metallic)
    orm = _limit(np.stack([np.full((h, w), 255, np.uint8), g, b], axis=2), max_size)
    return (
        encode_png(orm),
        encode_png(orm[..., 1]) if rough is not None else None,
        encode_png(orm[..., 2]) if metal is not None else None,
    )


def pbr_from_builtin(
    builtin: Mapping[str, Any], *, part_name: str, resolve_ref: ResolveRef | None = None,
    max_texture_size: int | None = None,
) -> PbrMaterial:
    """A part's built-in material (`PartMesh.builtin_material`), converted as the renderer does.

    Without `resolve_ref` a built-in texture cannot be found and only the constant albedo is kept.
    """
    builtin = dict(builtin)
    builtin.setdefault("name", f"builtin_{part_name}")
    if resolve_ref is None:
        builtin.pop("texture", None)
    spec = material_from_builtin(builtin, resolve_ref or Path)
    out = pbr_from_spec(spec, max_texture_size=max_texture_size)
    out.builtin = True
    return out


def pbr_materials(
    shape: Any, materials: list[Any] | None, *, resolve_ref: ResolveRef | None = None,
    max_texture_size: int | None = None,
) -> list[PbrMaterial]:
    """One PbrMaterial per part of `shape` (`materials[i]` for `shape.parts[i]`, None = built-in).

    Equal specs (same name and refinement) are converted once, so shared materials share images.
    """
    materials = list(materials) if materials is not None else [None] * len(shape.parts)
    if len(materials) != len(shape.parts):
        raise ValueError(f"{len(materials)} materials for {len(shape.parts)} parts")
    cache: dict[str, PbrMaterial] = {}
    out: list[PbrMaterial] = []
    for part, spec in zip(shape.parts, materials, strict=True):
        if spec is None:
            out.append(pbr_from_builtin(part.builtin_material or {}, part_name=part.name,
                                        resolve_ref=resolve_ref, max_texture_size=max_texture_size))
            continue
        refinement = getattr(spec, "refinement", None)
        key = f"{spec.name}|{refinement.to_dict() if refinement is not None else ''}"
        if key not in cache:
            cache[key] = pbr_from_spec(spec, max_texture_size=max_texture_size)
        out.append(cache[key])
    return out
