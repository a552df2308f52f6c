"""What a render is made of, as plain data: materials, UV jitter, environment maps.

The texture-scale formula of section 5.1 lives here (`uv_matrix`) and nowhere else: a part's UVs
are multiplied by 1/sqrt(D_i) (D_i = `PartMesh.uv_density` = A_uv / A_world, so the scaled UVs have
unit density: one UV unit per world unit) and by 1/material.scale (one texture tile covers
`material.scale` world units), then the `UVTransform` jitter (scale, rotation, offset) is applied
on top. A material whose ``scale`` is None keeps the mesh's own UVs (built-in source textures were
authored for them) and only the jitter applies.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

CHANNELS: tuple[str, ...] = ("albedo", "roughness", "metallic", "specular", "normal", "height")


@dataclass
class MaterialSpec:
    """A material to put on a part: SVBRDF maps by channel and/or analytic parameters.

    ``maps``: channel -> image path (channels in `CHANNELS`; albedo sRGB, the others linear, normal
    in the OpenGL convention). ``params``: analytic values used where a map is absent: ``albedo``
    [r, g, b] sRGB 0..1, ``roughness``, ``metallic``, ``specular`` floats. ``scale``: world size of
    one texture tile in unit-cube units, or None to keep the mesh's UVs unchanged.
    """

    name: str
    substance: str | None = None
    maps: dict[str, Path] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)
    scale: float | None = 0.25
    refinement: Refinement | None = None  # fitted to one part's photo (`fit.refine`); None: the library's look

    def __post_init__(self) -> None:
        unknown = set(self.maps) - set(CHANNELS)
        if unknown:
            raise ValueError(f"material {self.name}: unknown map channel(s) {sorted(unknown)}")
        self.maps = {k: Path(v) for k, v in self.maps.items()}
        if self.scale is not None and not self.scale > 0:
            raise ValueError(f"material {self.name}: scale must be > 0, got {self.scale}")


@dataclass(frozen=True)
class Refinement:
    """A library material adjusted to one part's photo (`fit.refine`): a few parameters, never texels.

    ``tint`` multiplies the linear base colour (map or constant), ``roughness_scale`` the roughness,
    both clipped to 0..1 after (what glTF factors can express, and what the renderer renders);
    ``uv_scale``/``uv_rotation`` (radians) transform the UVs after the texture-scale formula and the
    jitter: uv' = R(uv_rotation) @ (uv_scale * uv). Why a separate record rather than new texture
    files: the library texture stays shared, and every format can carry the few numbers as its own
    factors (glTF baseColorFactor, KHR_texture_transform; MTL Kd).
    """

    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    roughness_scale: float = 1.0
    uv_scale: float = 1.0
    uv_rotation: float = 0.0

    @property
    def has_uv(self) -> bool:
        return self.uv_scale != 1.0 or self.uv_rotation != 0.0

    def uv_transform(self) -> UVTransform:
        return UVTransform(self.uv_scale, self.uv_rotation)

    def to_dict(self) -> dict[str, Any]:
        return {"tint": [float(t) for t in self.tint], "roughness_scale": float(self.roughness_scale),
                "uv_scale": float(self.uv_scale), "uv_rotation": float(self.uv_rotation)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Refinement:
        tint = data.get("tint", (1.0, 1.0, 1.0))
        return cls((float(tint[0]), float(tint[1]), float(tint[2])), float(data.get("roughness_scale", 1.0)),
                   float(data.get("uv_scale", 1.0)), float(data.get("uv_rotation", 0.0)))


@dataclass(frozen=True)
class UVTransform:
    """Augmentation on top of the texture-scale formula: scale, rotation (radians), offset (UV units).

    Applied as uv' = R(rotation) @ (scale * uv) + offset, in that order.
    """

    scale: float = 1.0
    rotation: float = 0.0
    offset: tuple[float, float] = (0.0, 0.0)

    def to_dict(self) -> dict[str, Any]:
        return {"scale": self.scale, "rotation": self.rotation, "offset": list(self.offset)}


@dataclass(frozen=True)
class EnvmapSpec:
    """An environment map (lat-long .exr/.hdr, +y up) with a radiance scale and a rotation about +y."""

    path: Path
    scale: float = 1.0
    rotation: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))


def srgb_to_linear(value: Any) -> np.ndarray:
    """The sRGB electro-optical transfer function (IEC 61966-2-1), elementwise on 0..1 values."""
    c = np.clip(np.asarray(value, np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(value: Any) -> np.ndarray:
    """Inverse of `srgb_to_linear` (values clipped to 0..1 first)."""
    c = np.clip(np.asarray(value, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)


def uv_matrix(uv_density: float, material_scale: float | None, jitter: UVTransform | None = None) -> np.ndarray:
    """3x3 homogeneous UV transform of a part: the texture-scale formula, then the jitter.

    uv' = J @ S @ uv with S = diag(k, k) and k = 1/sqrt(D_i)/material_scale (k = 1 when the
    material keeps the mesh UVs), and J = translate(offset) @ rotate(rotation) @ scale(jitter.scale).
    """
    if material_scale is None:
        k = 1.0
    else:
        density = uv_density if uv_density > 0 and math.isfinite(uv_density) else 1.0
        k = 1.0 / math.sqrt(density) / material_scale
    matrix = np.diag([k, k, 1.0])
    if jitter is not None:
        c, s = math.cos(jitter.rotation), math.sin(jitter.rotation)
        j = np.array(
            [
                [jitter.scale * c, -jitter.scale * s, jitter.offset[0]],
                [jitter.scale * s, jitter.scale * c, jitter.offset[1]],
                [0.0, 0.0, 1.0],
            ]
        )
        matrix = j @ matrix
    return matrix


def refined_uv_matrix(uv_density: float, material: Any, jitter: UVTransform | None = None) -> np.ndarray:
    """`uv_matrix` of a part with `material` (a MaterialSpec or None), then the material's refinement UVs."""
    matrix = uv_matrix(uv_density, getattr(material, "scale", None), jitter)
    refinement = getattr(material, "refinement", None)
    if refinement is not None and refinement.has_uv:
        matrix = uv_matrix(1.0, None, refinement.uv_transform()) @ matrix
    return matrix


def apply_uv_matrix(uvs: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Transform (N, 2) UVs by a 3x3 homogeneous matrix (float32 out)."""
    uv = np.asarray(uvs, np.float64)
    return (uv @ matrix[:2, :2].T + matrix[:2, 2]).astype(np.float32)


def material_from_builtin(builtin: Mapping[str, Any], resolve: Callable[[str], Path]) -> MaterialSpec:
    """The MaterialSpec of a part's built-in material (`PartMesh.builtin_material`).

    ``builtin``: ``{"albedo": [r, g, b] sRGB, "roughness", "metallic", "texture": blob ref, "name"}``;
    `resolve` turns the texture's blob ref into a file path (e.g. ``BlobStore.resolve``). The
    texture, when present, is the albedo map and keeps the mesh's own UVs (``scale=None``).
    """
    albedo = builtin.get("albedo", [0.8, 0.8, 0.8])
    if len(albedo) != 3:
        raise ValueError(f"built-in material {builtin.get('name')!r}: albedo needs 3 values, got {albedo!r}")
    params = {
        "albedo": [float(a) for a in albedo],
        "roughness": float(builtin.get("roughness", 0.5)),
        "metallic": float(builtin.get("metallic", 0.0)),
    }
    maps: dict[str, Path] = {}
    texture = builtin.get("texture")
    if texture:
        maps["albedo"] = Path(resolve(str(texture)))
    return MaterialSpec(name=str(builtin.get("name") or "builtin"), maps=maps, params=params, scale=None)
