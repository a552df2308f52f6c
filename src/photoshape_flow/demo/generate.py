"""`generate_demo`: a complete, self-contained input collection with ground truth, from a seed.

Writes <out_dir>/
    shapes/<id>.obj + .mtl          the shape collection (ingest input)
    materials/<name>/               SVBRDF folders with material.json (ingest input)
    envmaps/<name>.hdr              studio environment maps (ingest input)
    exemplars/<stem>.jpg            photo-like exemplars (ingest input)
    groundtruth.json                what evaluation compares against: the format of docs/evaluation.md
                                    plus the demo's own fields (see `groundtruth`)
    groundtruth/masks/<stem>.png    part-index masks in the exemplars' native frame
    groundtruth/shapes/             held-out shapes seen only in exemplars
    groundtruth/envmaps/            held-out studios used only for exemplars

Deterministic in (size, seed) and idempotent: files whose bytes would not change are left alone and
an exemplar whose inputs hash the same as the recorded one is not rendered again.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photoshape_flow.demo.envmaps import studio_specs, write_studio
from photoshape_flow.demo.exemplars import encode_mask, plan_exemplars, render_exemplar
from photoshape_flow.demo.groundtruth import GROUNDTRUTH_FORMAT, GROUNDTRUTH_VERSION
from photoshape_flow.demo.material_catalogue import select_recipes
from photoshape_flow.demo.materials import MAP_CHANNELS, write_material
from photoshape_flow.demo.shapes import collection_shapes, heldout_shapes, shape_entry, write_shape
from photoshape_flow.demo.sizes import SIZES, DemoSize, SizePreset
from photoshape_flow.demo.writing import sha256_hex, write_bytes, write_text
from photoshape_flow.hashing import stable_hash
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol

log = logging.getLogger(__name__)

GENERATOR_VERSION = "1"
@dataclass(frozen=True)
class DemoManifest:
    """What `generate_demo` wrote (absolute paths) and how long each stage took."""

    root: Path
    size: str
    seed: int
    shapes: tuple[Path, ...]
    materials: tuple[Path, ...]
    envmaps: tuple[Path, ...]
    exemplars: tuple[Path, ...]
    groundtruth: Path
    rendered: int = 0  # exemplars rendered by this call (the rest were up to date)
    timings: dict[str, float] = field(default_factory=dict)


# -- entry point ----------------------------------------------------------------------------------


def _previous_exemplars(previous_gt: Any) -> dict[str, Any]:
    """stem -> the exemplar entry of the file being replaced (a list since version 2, a dict before), so
    an unchanged exemplar is not rendered again."""
    entries = previous_gt.get("exemplars", {}) if isinstance(previous_gt, dict) else {}
    if isinstance(entries, dict):
        return entries
    return {e["source_id"]: e for e in entries if isinstance(e, dict) and isinstance(e.get("source_id"), str)}


def generate_demo(
    out_dir: Path,
    size: DemoSize = "tiny",
    seed: int = 0,
    *,
    renderer: RendererProtocol | None = None,
    preset: SizePreset | None = None,
    source: str | None = None,
) -> DemoManifest:
    """Generate (or bring up to date) the demo collection of `size` in `out_dir`; see module docstring.

    `renderer`: a `photoshape_flow.render.renderer.Renderer` to reuse (one is created when exemplars need
    rendering and none is given). `preset`: custom counts instead of SIZES[size] (tests, experiments).
    `source`: the ingest source the ground truth names the exemplars and shapes by (default
    ``demo-<size>``, what `photoshape demo` ingests them as).
    """
    source = source or f"demo-{size}"
    if size not in SIZES:
        raise ValueError(f"unknown demo size {size!r}; expected one of {sorted(SIZES)}")
    preset = preset or SIZES[size]
    if preset.shapes < 1 or preset.per_substance < 1 or preset.envmaps < 1 or preset.heldout_envmaps < 1:
        raise ValueError(f"demo preset needs at least one shape, material per substance and envmap: {preset}")
    root = Path(out_dir).resolve()
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    collection = collection_shapes(seed, preset.shapes)
    heldout = heldout_shapes(seed, preset.heldout_shapes, collection)
    shape_paths, shape_hash, shapes_json = [], {}, {}
    for f in collection:
        path, digest = write_shape(root / "shapes", f)
        shape_paths.append(path)
        shape_hash[f.source_id] = digest
        shapes_json[f.source_id] = shape_entry(f, f"shapes/{f.source_id}.obj", True, None)
    for f, parent in heldout:
        _, digest = write_shape(root / "groundtruth" / "shapes", f)
        shape_hash[f.source_id] = digest
        shapes_json[f.source_id] = shape_entry(f, f"groundtruth/shapes/{f.source_id}.obj", False, parent)
    timings["shapes"] = time.perf_counter() - t0

    gt_path = root / "groundtruth.json"
    previous_gt: dict[str, Any] = {}
    if gt_path.is_file():
        try:
            previous_gt = json.loads(gt_path.read_text())
        except (OSError, json.JSONDecodeError):
            previous_gt = {}
    old_stamps: dict[str, str] = previous_gt.get("stamps", {}) if isinstance(previous_gt, dict) else {}
    stamps: dict[str, str] = {}

    def fresh(rel: str, stamp: str, files: list[str]) -> bool:
        """True when `rel` was generated from the same inputs and its files are all still there."""
        stamps[rel] = stamp
        return old_stamps.get(rel) == stamp and all((root / rel / f if f else root / rel).is_file() for f in files)

    t = time.perf_counter()
    recipes = select_recipes(preset.per_substance)
    material_dirs = {}
    for r in recipes:
        rel = f"materials/{r.name}"
        stamp = stable_hash([asdict(r), seed, preset.texture_resolution, GENERATOR_VERSION])
        if not fresh(rel, stamp, [f"{ch}.png" for ch in MAP_CHANNELS] + ["material.json"]):
            write_material(root / rel, r, seed, preset.texture_resolution)
        material_dirs[r.name] = root / rel
    timings["materials"] = time.perf_counter() - t

    t = time.perf_counter()
    studios = studio_specs(seed, preset.envmaps, "studio")
    held_studios = studio_specs(seed, preset.heldout_envmaps, "heldout")
    envmap_paths: list[Path] = []
    held_paths: dict[str, Path] = {}
    for folder, specs in (("envmaps", studios), ("groundtruth/envmaps", held_studios)):
        for spec in specs:
            rel = f"{folder}/{spec.name}.hdr"
            stamp = stable_hash([spec.to_json(), preset.envmap_width, GENERATOR_VERSION])
            if not fresh(rel, stamp, [""]):
                write_studio(root / rel, spec, preset.envmap_width)
            if folder == "envmaps":
                envmap_paths.append(root / rel)
            else:
                held_paths[spec.name] = root / rel
    timings["envmaps"] = time.perf_counter() - t

    t = time.perf_counter()
    previous = _previous_exemplars(previous_gt)
    furniture_by_id = {f.source_id: f for f in collection} | {f.source_id: f for f, _ in heldout}
    recipe_by_name = {r.name: r for r in recipes}
    plans = plan_exemplars(seed, preset, collection, heldout, recipes, held_studios)
    exemplars_json: list[dict[str, Any]] = []
    exemplar_paths = []
    rendered = 0
    for plan in plans:
        furniture = furniture_by_id[plan.shape_id]
        spec_hash = sha256_hex(
            json.dumps(
                {
                    "plan": asdict(plan),
                    "shape": shape_hash[plan.shape_id],
                    "version": GENERATOR_VERSION,
                    "textures": preset.texture_resolution,
                    "envmap_width": preset.envmap_width,
                    "seed": seed,
                },
                sort_keys=True,
            )
        )
        image_rel, mask_rel = f"exemplars/{plan.stem}.jpg", f"groundtruth/masks/{plan.stem}.png"
        old = previous.get(plan.stem, {})
        up_to_date = (
            old.get("spec_hash") == spec_hash
            and (root / image_rel).is_file()
            and (root / mask_rel).is_file()
            and "visible_parts" in old
        )
        if up_to_date:
            visible = list(old["visible_parts"])
        else:
            if renderer is None:
                renderer = default_renderer()
            jpeg, mask = render_exemplar(
                renderer, furniture, plan, material_dirs, recipe_by_name, held_paths[plan.envmap["name"]]
            )
            write_bytes(root / image_rel, jpeg)
            write_bytes(root / mask_rel, encode_mask(mask))
            present = set(np.unique(mask).tolist())
            visible = [p.name for i, p in enumerate(furniture.parts, start=1) if i in present]
            rendered += 1
            log.info("demo exemplar %s: %s (%d parts visible)", plan.stem, plan.shape_id, len(visible))
        exemplar_paths.append(root / image_rel)
        exemplars_json.append({  # the ground-truth format's fields (docs/evaluation.md), then the demo's
            "source": source,
            "source_id": plan.stem,
            "shape": {"source": source, "source_id": plan.shape_id},
            "in_collection": plan.in_collection,
            "camera": plan.camera,
            "parts": {
                name: {"material": plan.materials[name], "substance": plan.substances[name]} for name in plan.materials
            },
            "mask": {"path": mask_rel, "kind": "part",
                     "values": {str(i): p.name for i, p in enumerate(furniture.parts, start=1)}},
            "lighting": {"envmap": held_paths[plan.envmap["name"]].relative_to(root).as_posix(),
                         "rotation": plan.envmap["rotation"], "scale": plan.envmap["scale"]},
            "image": image_rel,
            "size": plan.size,
            "similar_to": plan.similar_to,
            "visible_parts": visible,
            "envmap": plan.envmap,
            "degradation": plan.degradation,
            "spec_hash": spec_hash,
        })
    timings["exemplars"] = time.perf_counter() - t

    groundtruth = {
        "format": GROUNDTRUTH_FORMAT,
        "version": GROUNDTRUTH_VERSION,
        "size": size,
        "seed": seed,
        "generator": f"photoshape_flow demo {GENERATOR_VERSION}",
        "license": "CC0-1.0",
        "preset": asdict(preset),
        "shapes": shapes_json,
        "materials": {r.name: {"substance": r.substance, "path": f"materials/{r.name}"} for r in recipes},
        "envmaps": [s.name for s in studios],
        "heldout_envmaps": [s.name for s in held_studios],
        "exemplars": exemplars_json,
        "stamps": stamps,
    }
    write_text(gt_path, json.dumps(groundtruth, indent=1, sort_keys=True) + "\n")
    timings["total"] = time.perf_counter() - t0
    log.info("demo %s (seed %d) in %s: %d exemplars rendered, %.1f s", size, seed, root, rendered, timings["total"])
    return DemoManifest(
        root=root,
        size=size,
        seed=seed,
        shapes=tuple(shape_paths),
        materials=tuple(material_dirs[r.name] for r in recipes),
        envmaps=tuple(envmap_paths),
        exemplars=tuple(exemplar_paths),
        groundtruth=gt_path,
        rendered=rendered,
        timings=timings,
    )
