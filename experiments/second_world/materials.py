"""The world's materials: real PBR scans plus the demo's procedural SVBRDFs, and the held-out variants.

The library (ingested into the collection) is every scan of `shared/data/materials` (wood, metal,
plastic: no real leather or fabric scan with a clear licence exists there, so those two substances
come from the demo's procedural materials only) plus the first `DEMO_PER_SUBSTANCE` demo recipes of
each substance. The open-library share renders *variants* (hue rotated, roughness and tile size
scaled) that are written beside the world, never into `collection/`, each with its parent's name
in the ground truth and its own mean albedo (CIELAB) for the Delta E of issue 26.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from experiments.second_world.plan import LibraryMaterial, Variant
from photoshape_flow.demo.material_catalogue import select_recipes
from photoshape_flow.demo.materials import write_material

DEMO_PER_SUBSTANCE = 4
DEMO_SEED = 7  # the procedural maps' own seed (fixed: the library does not change with the world's seed)

# Real scans of shared/data/materials: substance, tile size (unit-cube units ~ metres), normal map
# convention, licence (data/README.md). A scan without a roughness map renders with `roughness`.
REAL_SCANS: dict[str, dict[str, Any]] = {
    "wood_rosewood_veneer1": {
        "substance": "wood", "scale": 0.6, "normal": "gl", "roughness": None, "license": "CC0-1.0",
        "attribution": "Poly Haven, rosewood_veneer1 (via RobotLocomotion/models)"},
    "wood_hardwood2": {
        "substance": "wood", "scale": 1.0, "normal": None, "roughness": None, "license": "MIT",
        "attribution": "three.js examples/textures hardwood2 (mrdoob/three.js, MIT)"},
    "metal_scratched_gold_01": {
        "substance": "metal", "scale": 0.5, "normal": "gl", "roughness": None, "license": "CC0-1.0",
        "attribution": "cgbookcase Scratched Gold 01 (via three.js examples)"},
    "plastic_carbon_fibre": {
        "substance": "plastic", "scale": 0.15, "normal": "gl", "roughness": 0.35, "license": "MIT",
        "attribution": "three.js examples/textures/carbon (mrdoob/three.js, MIT)"},
}
MAP_NAMES = {"albedo": ("albedo",), "roughness": ("roughness",), "metallic": ("metallic",),
             "normal": ("normal_gl", "normal")}


@dataclass(frozen=True)
class MaterialAsset:
    """A material as Blender needs it: map files (or constants) and the tile size."""

    name: str
    substance: str
    scale: float
    albedo: Path
    roughness: Path | float
    metallic: Path | float
    normal: Path | None
    origin: str  # "scan" | "demo" | "variant"
    license: str
    attribution: str

    def library(self) -> LibraryMaterial:
        return LibraryMaterial(self.name, self.substance, self.scale)


def _find(folder: Path, names: tuple[str, ...]) -> Path | None:
    for name in names:
        for ext in (".png", ".jpg", ".jpeg"):
            if (folder / f"{name}{ext}").is_file():
                return folder / f"{name}{ext}"
    return None


def write_library(shared_materials: Path, dest: Path) -> list[MaterialAsset]:
    """Copy the real scans and write the demo materials into `dest` (the collection's materials)."""
    assets: list[MaterialAsset] = []
    for name, info in sorted(REAL_SCANS.items()):
        src = shared_materials / name
        if not src.is_dir():
            print(f"{src}: real scan missing; left out of the library")
            continue
        folder = dest / name
        shutil.copytree(src, folder, dirs_exist_ok=True)
        sidecar = {"name": name, "substance": info["substance"], "scale": info["scale"],
                   "normal": info["normal"] or "gl", "source": "shared/data/materials",
                   "license": info["license"], "attribution": info["attribution"], "source_url": None}
        (folder / "material.json").write_text(json.dumps(sidecar, indent=2) + "\n")
        assets.append(_asset(folder, name, info["substance"], info["scale"], "scan", info["license"],
                             info["attribution"], roughness=info["roughness"], use_normal=info["normal"] is not None))
    for recipe in select_recipes(DEMO_PER_SUBSTANCE):
        folder = dest / recipe.name
        write_material(folder, recipe, DEMO_SEED)
        assets.append(_asset(folder, recipe.name, recipe.substance, recipe.scale, "demo", "CC0-1.0",
                             f"photoshape_flow demo, procedural ({recipe.pattern}, seed {DEMO_SEED})"))
    return assets


def _asset(folder: Path, name: str, substance: str, scale: float, origin: str, license: str, attribution: str,
           roughness: float | None = None, use_normal: bool = True) -> MaterialAsset:
    albedo = _find(folder, MAP_NAMES["albedo"])
    if albedo is None:
        raise FileNotFoundError(f"{folder}: no albedo map")
    rough_map = _find(folder, MAP_NAMES["roughness"])
    metal_map = _find(folder, MAP_NAMES["metallic"])
    return MaterialAsset(
        name=name, substance=substance, scale=scale, albedo=albedo,
        roughness=rough_map if rough_map is not None else (roughness if roughness is not None else 0.5),
        metallic=metal_map if metal_map is not None else (1.0 if substance == "metal" else 0.0),
        normal=_find(folder, MAP_NAMES["normal"]) if use_normal else None,
        origin=origin, license=license, attribution=attribution,
    )


def shift_hue(rgb: np.ndarray, degrees: float) -> np.ndarray:
    """8-bit RGB with its hue rotated (HSV; greys stay grey)."""
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV_FULL).astype(np.int32)
    hsv[..., 0] = (hsv[..., 0] + round(degrees / 360 * 256)) % 256
    return cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB_FULL)


def mean_lab(rgb: np.ndarray) -> list[float]:
    """CIELAB (D65) of the mean linear colour of an 8-bit sRGB image: the material's mean albedo."""
    lin = np.where(rgb / 255.0 <= 0.04045, rgb / 255.0 / 12.92, ((rgb / 255.0 + 0.055) / 1.055) ** 2.4)
    mean = lin.reshape(-1, 3).mean(axis=0)
    srgb = np.where(mean <= 0.0031308, 12.92 * mean, 1.055 * mean ** (1 / 2.4) - 0.055)
    pixel = np.clip(srgb * 255.0, 0, 255).astype(np.float32).reshape(1, 1, 3) / 255.0
    return [round(float(v), 2) for v in cv2.cvtColor(pixel, cv2.COLOR_RGB2Lab).reshape(3)]


def read_rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(f"{path}: not a readable image")
    return image[..., ::-1].copy()


def write_variant(parent: MaterialAsset, variant: Variant, dest: Path) -> MaterialAsset:
    """The variant's maps (albedo hue-rotated, roughness scaled) under dest/<name>, with a
    material.json so it could be ingested later (an open-library experiment), never by this build."""
    folder = dest / variant.name
    folder.mkdir(parents=True, exist_ok=True)
    albedo = folder / "albedo.png"
    if not albedo.is_file():
        cv2.imwrite(str(albedo), shift_hue(read_rgb(parent.albedo), variant.hue_shift_deg)[..., ::-1])
    roughness: Path | float
    if isinstance(parent.roughness, Path):
        roughness = folder / "roughness.png"
        if not roughness.is_file():
            grey = cv2.imread(str(parent.roughness), cv2.IMREAD_GRAYSCALE).astype(np.float64)
            cv2.imwrite(str(roughness), np.clip(grey * variant.roughness_scale, 0, 255).astype(np.uint8))
    else:
        roughness = round(min(1.0, parent.roughness * variant.roughness_scale), 4)
    scale = round(parent.scale / variant.uv_scale, 4)
    sidecar = {"name": variant.name, "substance": parent.substance, "scale": scale, "normal": "gl",
               "source": f"second_world variant of {parent.name}", "license": parent.license,
               "attribution": f"derived from {parent.attribution}", "source_url": None,
               "variant": {"of": parent.name, "hue_shift_deg": variant.hue_shift_deg,
                           "roughness_scale": variant.roughness_scale, "uv_scale": variant.uv_scale}}
    (folder / "material.json").write_text(json.dumps(sidecar, indent=2) + "\n")
    return MaterialAsset(name=variant.name, substance=parent.substance, scale=scale, albedo=albedo,
                         roughness=roughness, metallic=parent.metallic, normal=parent.normal, origin="variant",
                         license=parent.license, attribution=sidecar["attribution"])
