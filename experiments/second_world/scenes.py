"""From a plan to what Blender renders, and from Blender's output to a product photo and its truth.

`scene_description` is the JSON contract with `blender_render.py` (pure: paths and numbers).
`finish_photo` composites the transparent render over white and JPEG-compresses it like a
catalogue photo; `groundtruth_entry` writes the exemplar in the ground-truth format of
docs/evaluation.md (version 2), with the world's own extra keys (the material each part really
shows, its mean albedo, the lighting) beside the format's fields.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from experiments.second_world.materials import MaterialAsset
from experiments.second_world.plan import ExemplarPlan
from photoshape_flow.render.camera import Camera

TARGET_MEAN_RADIANCE = 0.6  # the demo studios' mean radiance: exemplars share the collection's exposure
WORLD_SOURCE = "second-world"  # `photoshape ingest exemplars <world>/exemplars --source second-world`


def hdri_mean(path: Path) -> float:
    """Mean luminance of an equirectangular HDR (solid-angle weighted), for strength normalisation."""
    image = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(f"{path}: not a readable HDR image")
    rgb = image[..., ::-1].astype(np.float64)
    lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
    rows = np.cos((np.arange(lum.shape[0]) + 0.5) / lum.shape[0] * math.pi - math.pi / 2)
    return float((lum * rows[:, None]).sum() / (rows.sum() * lum.shape[1]))


def project_rotation(blender_z: float) -> float:
    """The HDRI rotation in the project's convention (`EnvmapSpec.rotation`, radians about +y, Mitsuba's
    lat-long) that shows what Blender shows with a Mapping-node Z rotation `blender_z`: pi/2 - r.
    Measured, not only derived: the background of both renderers at two cameras and rotations
    correlates 0.82 and 0.95 (log radiance) for pi/2 - r, at most 0.35 for r, -r or r - pi/2."""
    return (math.pi / 2 - blender_z) % (2 * math.pi)


def _value(v: Path | float) -> str | float:
    return str(v) if isinstance(v, Path) else float(v)


def scene_description(plan: ExemplarPlan, parts: list[dict[str, Any]], assets: dict[str, MaterialAsset],
                      mesh: Path, hdri: Path, hdri_mean_radiance: float, outputs: dict[str, Path],
                      resolution: int, samples: int) -> dict[str, Any]:
    """The scene JSON of one exemplar. `parts`: the shape's part records (name, object, uv_density);
    `assets`: material name -> asset (variants under their own names)."""
    camera = Camera.from_dict(plan.camera)
    part_specs = []
    for index, record in enumerate(parts, start=1):
        asset = assets[plan.parts[record["name"]].shown]
        density = record["uv_density"] if record["uv_density"] > 0 and math.isfinite(record["uv_density"]) else 1.0
        part_specs.append({
            "object": record["object"], "index": index, "name": record["name"], "material": asset.name,
            "albedo": str(asset.albedo), "roughness": _value(asset.roughness), "metallic": _value(asset.metallic),
            "normal": str(asset.normal) if asset.normal is not None else None,
            "uv_scale": round(1.0 / math.sqrt(density) / asset.scale, 6),  # render.specs.uv_matrix's k
        })
    return {
        "stem": plan.stem, "mesh": str(mesh), "resolution": resolution, "samples": samples,
        "seed": plan.render_seed % (2**31 - 1),
        "camera": {"position": [round(float(c), 6) for c in camera.position], "target": [0.0, 0.0, 0.0],
                   "up": [0.0, 1.0, 0.0], "fov_deg": camera.fov},
        "hdri": {"path": str(hdri), "rotation": plan.envmap["rotation"],
                 "strength": round(plan.envmap["strength"] * TARGET_MEAN_RADIANCE / max(hdri_mean_radiance, 1e-6), 5)},
        "parts": part_specs,
        "outputs": {k: str(v) for k, v in outputs.items()},
    }


def finish_photo(rgba: np.ndarray, quality: int) -> bytes:
    """A 16- or 8-bit RGBA render (straight alpha, display-referred) over white, as JPEG bytes."""
    scale = 65535.0 if rgba.dtype == np.uint16 else 255.0
    image = rgba.astype(np.float64) / scale
    rgb, alpha = image[..., :3], image[..., 3:4]
    over = rgb * alpha + (1.0 - alpha)
    out = np.clip(np.round(over * 255.0), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def read_render(path: Path) -> np.ndarray:
    """Blender's PNG as RGBA (cv2 reads BGRA)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if image is None or image.ndim != 3 or image.shape[2] != 4:
        raise FileNotFoundError(f"{path}: missing or not an RGBA render")
    return image[..., [2, 1, 0, 3]]


def mask_from_render(path: Path, parts: int) -> np.ndarray:
    """The part-index mask (uint8, 0 = background) from Blender's Raw-view emission render."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if image is None:
        raise FileNotFoundError(f"{path}: missing mask render")
    value = image[..., 0] if image.ndim == 2 else image[..., 2]  # the red channel (all channels are equal)
    if image.ndim == 3 and image.shape[2] == 4:
        value = np.where(image[..., 3] > 127, value, 0)
    value = value.astype(np.uint8)
    if int(value.max()) > parts:
        raise ValueError(f"{path}: mask value {int(value.max())} above the part count {parts}")
    return value


def groundtruth_entry(plan: ExemplarPlan, parts: list[dict[str, Any]], assets: dict[str, MaterialAsset],
                      albedo_lab: dict[str, list[float]], scene: dict[str, Any], hdri_name: str,
                      mask_rel: str) -> dict[str, Any]:
    """One exemplar in the ground-truth format (version 2) plus the world's own keys."""
    truth_parts: dict[str, Any] = {}
    for record in parts:
        part = plan.parts[record["name"]]
        shown = assets[part.shown]
        entry: dict[str, Any] = {"material": part.material, "substance": part.substance,
                                 "shown_material": shown.name, "albedo_lab": albedo_lab[shown.name]}
        if part.variant is not None:
            entry["variant"] = {"of": part.variant.of, "hue_shift_deg": part.variant.hue_shift_deg,
                                "roughness_scale": part.variant.roughness_scale, "uv_scale": part.variant.uv_scale}
        truth_parts[record["name"]] = entry
    return {
        "source": WORLD_SOURCE,
        "source_id": plan.stem,
        "shape": {"source": plan.shape.source, "source_id": plan.shape.source_id},
        "in_collection": plan.in_collection,
        "camera": {k: round(float(plan.camera[k]), 6) for k in ("azimuth", "elevation", "distance", "fov")},
        "parts": truth_parts,
        "mask": {"path": mask_rel, "kind": "part",
                 "values": {str(i): r["name"] for i, r in enumerate(parts, start=1)}},
        "open_library": plan.open_library,
        "lighting": {"envmap": hdri_name, "rotation": round(project_rotation(plan.envmap["rotation"]), 6),
                     "scale": scene["hdri"]["strength"], "rotation_blender_z": plan.envmap["rotation"]},
        "render": {"renderer": "blender-cycles", "resolution": scene["resolution"], "samples": scene["samples"],
                   "seed": scene["seed"], "jpeg_quality": plan.jpeg_quality, "view_transform": "Standard"},
    }
