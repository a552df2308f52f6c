"""One synthetic training example: beauty render plus exact per-pixel part, material and substance labels.

The material-ID and substance-ID maps are *derived* from the renderer's exact part-ID map through the
spec's part -> material assignment (a lookup table indexed by part index), so labels and assignment
agree by construction. Over-exposed renders are not silently dropped: `saturated_fraction` (share of
foreground pixels with any sRGB channel >= 0.99) is returned and `rejected` says whether it exceeds
the threshold (0.05, as the original collector used), so the pipeline records them as `rejected`.

"Foreground" here means pixels of a part that the beauty pass covers fully (alpha >= 0.999): edge
pixels are blended with the white background, and on thin legs and frames at 128 px they were a
large share of the part pixels, which rejected a third of the renders for being "white" there.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from photoshape_flow.render import Camera, EnvmapSpec, UVTransform
from photoshape_flow.synth.spec import RenderSpec
from photoshape_flow.vocab import SUBSTANCE_LABELS

SATURATION_LEVEL = 0.99
SATURATION_THRESHOLD = 0.05
FULL_COVERAGE = 0.999


@dataclass
class TrainingExample:
    srgb: np.ndarray  # (H, W, 3) uint8, white background
    hdr: np.ndarray  # (H, W, 3) float32, linear radiance
    part_ids: np.ndarray  # (H, W) uint16, 0 = background, else PartMesh.index
    material_ids: np.ndarray  # (H, W) uint16, 0 = background, else material DB id
    substance_ids: np.ndarray  # (H, W) uint8, index into SUBSTANCE_LABELS (0 = background)
    saturated_fraction: float
    rejected: bool

    @property
    def foreground_fraction(self) -> float:
        return float((self.part_ids > 0).mean())


def saturated_fraction(srgb: np.ndarray, foreground: np.ndarray, level: float = SATURATION_LEVEL) -> float:
    """Share of foreground pixels with any channel >= `level` (sRGB in 0..1); 0 without foreground."""
    fg = np.asarray(foreground, bool)
    if not fg.any():
        return 0.0
    image = np.asarray(srgb)
    values = image.astype(np.float32) / 255.0 if image.dtype == np.uint8 else image.astype(np.float32)
    saturated = (values >= level).any(axis=-1)
    return float(saturated[fg].mean())


def label_maps(part_ids: np.ndarray, spec: RenderSpec) -> tuple[np.ndarray, np.ndarray]:
    """Material-ID (uint16) and substance-ID (uint8) maps from a part-ID map and the spec's assignment.

    A part index present in the map but missing from the assignment is an error (labels would lie).
    """
    part_ids = np.asarray(part_ids)
    top = int(max([int(part_ids.max(initial=0)), *(p.index for p in spec.parts)]))
    material_lut = np.zeros(top + 1, np.uint16)
    substance_lut = np.zeros(top + 1, np.uint8)
    assigned = np.zeros(top + 1, bool)
    assigned[0] = True
    for part in spec.parts:
        if part.material_id <= 0 or part.material_id > np.iinfo(np.uint16).max:
            raise ValueError(f"{spec.key}: material id {part.material_id} does not fit a uint16 label map")
        material_lut[part.index] = part.material_id
        substance_lut[part.index] = SUBSTANCE_LABELS.index(part.substance)
        assigned[part.index] = True
    present = np.unique(part_ids)
    missing = [int(i) for i in present if not assigned[int(i)]]
    if missing:
        raise ValueError(f"{spec.key}: part indices {missing} are rendered but have no material")
    return material_lut[part_ids], substance_lut[part_ids]


def build_scene_inputs(
    shape_mesh: Any, spec: RenderSpec, material_specs: Mapping[int, Any], envmap_spec: Any
) -> tuple[Any, list[Any], list[Any], Any]:
    """Camera, per-part materials and UV transforms (in `shape_mesh.parts` order) and the envmap."""
    by_index = {p.index: p for p in spec.parts}
    materials: list[Any] = []
    uv_transforms: list[Any] = []
    for part in shape_mesh.parts:
        assignment = by_index.get(part.index)
        if assignment is None:
            raise ValueError(f"{spec.key}: part {part.index} ({part.name}) has no assignment in the spec")
        if assignment.material_id not in material_specs:
            raise ValueError(f"{spec.key}: material {assignment.material_id} is not available")
        materials.append(material_specs[assignment.material_id])
        uv = assignment.uv
        uv_transforms.append(UVTransform(scale=uv.scale, rotation=uv.rotation, offset=tuple(uv.offset)))
    cam = spec.camera
    camera = Camera(azimuth=cam.azimuth, elevation=cam.elevation, distance=cam.distance, fov=cam.fov)
    envmap = EnvmapSpec(
        path=envmap_spec.path,
        scale=float(getattr(envmap_spec, "scale", 1.0)) * spec.envmap.scale,
        rotation=float(getattr(envmap_spec, "rotation", 0.0)) + spec.envmap.rotation,
    )
    return camera, materials, uv_transforms, envmap


def render_training_example(
    renderer: Any,
    shape_mesh: Any,
    spec: RenderSpec,
    material_specs: Mapping[int, Any],
    envmap_spec: Any,
    size: int,
    spp: int,
    *,
    saturation_threshold: float = SATURATION_THRESHOLD,
) -> TrainingExample:
    """Render `spec` (beauty on white + exact part-ID pass) and derive its label maps.

    `material_specs`: material id -> `render.MaterialSpec`; `envmap_spec`: the envmap's
    `render.EnvmapSpec` (its own scale/rotation are multiplied/added with the spec's jitter).
    """
    camera, materials, uv_transforms, envmap = build_scene_inputs(shape_mesh, spec, material_specs, envmap_spec)
    beauty = renderer.beauty(
        shape_mesh,
        materials,
        camera,
        envmap,
        size=size,
        spp=spp,
        uv_transforms=uv_transforms,
        background="white",
        floor=False,
        seed=int(spec.seed % (2**31 - 1)),
        record=False,  # every training render has its own scene and seed: a recording would never replay
    )
    part_ids = np.asarray(renderer.part_ids(shape_mesh, camera, size=size)).astype(np.uint16)
    material_ids, substance_ids = label_maps(part_ids, spec)
    covered = part_ids > 0
    alpha = getattr(beauty, "alpha", None)
    if alpha is not None:
        covered &= np.asarray(alpha) >= FULL_COVERAGE
    fraction = saturated_fraction(beauty.srgb, covered)
    return TrainingExample(
        srgb=np.asarray(beauty.srgb, np.uint8),
        hdr=np.asarray(beauty.hdr, np.float32),
        part_ids=part_ids,
        material_ids=material_ids,
        substance_ids=substance_ids,
        saturated_fraction=fraction,
        rejected=fraction > saturation_threshold,
    )
