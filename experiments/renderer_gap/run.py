"""Same scene, two renderers: each part of the world's Blender Cycles photo against our Mitsuba render.

    PHOTOSHAPE_DATA_ROOT=/work/w-base python -m experiments.renderer_gap.run --world ../second-world \\
        --envmap-dir ../shared/data/envmaps

For every exemplar whose shape is in the collection, the world's own scene (`work/scenes/<stem>.json`:
mesh, camera, HDRI, turn and strength, the material each part shows) is rendered by our renderer at
the truth's camera, the world's resolution and samples, with the ingested shape and materials. Only
parts that show an ingested material are compared (not the open-library variants). Per part, over the
pixels both part masks agree on: the mean linear colour of each render (Blender's 16-bit PNG
display-referred under the Standard view, ours clipped and encoded the same way), as the luminance
ratio ours / Blender and the CIELAB difference of the means. Medians per substance and per material.
Read-only; output `<data root>/experiments/renderer_gap/results.json`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from experiments.common import results_dir
from experiments.second_world.scenes import mask_from_render, read_render
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.fit.appearance import to_lab
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.pipeline.render_inputs import material_spec
from photoshape_flow.render import Camera, EnvmapSpec
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.specs import linear_to_srgb, srgb_to_linear
from photoshape_flow.store import BlobStore

MIN_PIXELS = 30
LUMA = np.array([0.2126, 0.7152, 0.0722])


def part_stats(ours: np.ndarray, theirs: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """Mean linear colour of both renders over `mask`: luminance ratio and Delta E of the means."""
    a, b = ours[mask].mean(0), theirs[mask].mean(0)
    lab_a, lab_b = (to_lab(linear_to_srgb(np.clip(x, 0, 1))[None, None])[0, 0] for x in (a, b))
    return {"ratio": float((a @ LUMA) / max(b @ LUMA, 1e-6)), "delta_e": float(np.linalg.norm(lab_a - lab_b)),
            "dL": float(lab_a[0] - lab_b[0]), "pixels": int(mask.sum())}


def compare_scene(renderer: Any, scene: dict[str, Any], truth: dict[str, Any], mesh: ShapeMesh,
                  specs: dict[str, Any], envmap_dir: Path, spp: int, turn: float = 0.0,
                  azimuth: float = 0.0) -> dict[str, dict[str, float]]:
    """Per part name: `part_stats` of our render against Blender's, over the pixels both masks agree on;
    `turn` (light) and `azimuth` (camera), radians, put that error into our render."""
    light = truth["lighting"]
    envmap = EnvmapSpec(envmap_dir / Path(light["envmap"]).name, scale=light["scale"],
                        rotation=light["rotation"] + turn)
    camera = Camera.from_dict(truth["camera"])
    camera = camera.replace(azimuth=camera.azimuth + azimuth)
    size = int(scene["resolution"])
    shown = {p["name"]: p["material"] for p in scene["parts"]}
    materials = [specs.get(p.name) for p in mesh.parts]
    result = renderer.beauty(mesh, materials, camera, envmap, size=size, spp=spp, background="transparent",
                             record=False)
    alpha = result.alpha
    ours = np.clip(np.where(alpha[..., None] > 1e-6, result.hdr / np.maximum(alpha[..., None], 1e-6), 0), 0, 1)
    ours = srgb_to_linear(linear_to_srgb(ours))  # the same clip-and-encode as Blender's Standard view
    rgba = read_render(Path(scene["outputs"]["beauty"]))
    theirs = srgb_to_linear(rgba[..., :3].astype(np.float64) / 65535.0)
    their_ids = mask_from_render(Path(scene["outputs"]["mask"]), len(scene["parts"]))
    our_ids = renderer.part_ids(mesh, camera, size=size)
    our_index = {p.name: p.index for p in mesh.parts}
    out = {}
    for part in scene["parts"]:
        name = part["name"]
        if name not in specs or name not in our_index:
            continue
        mask = (their_ids == part["index"]) & (our_ids == our_index[name]) & (alpha > 0.99) & (rgba[..., 3] > 65000)
        if mask.sum() >= MIN_PIXELS:
            out[name] = part_stats(ours, theirs, mask) | {"material": shown[name]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", type=Path, required=True, help="the built second world")
    parser.add_argument("--envmap-dir", type=Path, required=True, help="where lighting.envmap names are found")
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--limit", type=int, default=0, help="at most this many exemplars (0: all)")
    parser.add_argument("--turn-deg", type=float, default=0.0, help="our light turned this far from the truth's")
    parser.add_argument("--azimuth-deg", type=float, default=0.0, help="our camera moved this far from the truth's")
    args = parser.parse_args()
    settings = get_settings()
    store = BlobStore(settings.blob_root)
    renderer = default_renderer(store)
    truths = {e["source_id"]: e for e in json.loads((args.world / "groundtruth.json").read_text())["exemplars"]}
    rows: list[dict[str, Any]] = []
    with Session(sa.create_engine(settings.resolved_database_url)) as session:  # read-only
        by_name = {mat.name: mat for mat in session.execute(sa.select(m.Material)).scalars()}
        shapes = {(s.source, s.source_id): s for s in session.execute(sa.select(m.Shape)).scalars()}
        done = 0
        for stem, truth in sorted(truths.items()):
            shape = shapes.get((truth["shape"]["source"], truth["shape"]["source_id"]))
            scene_path = args.world / "work" / "scenes" / f"{stem}.json"
            if shape is None or not shape.mesh_blob or not scene_path.is_file():
                continue
            scene = json.loads(scene_path.read_text())
            mesh = ShapeMesh.from_npz_bytes(store.read_bytes(shape.mesh_blob))
            specs = {p["name"]: material_spec(by_name[p["material"]], store)
                     for p in scene["parts"] if p["material"] in by_name}
            for name, stats in compare_scene(renderer, scene, truth, mesh, specs, args.envmap_dir, args.spp,
                                             math.radians(args.turn_deg), math.radians(args.azimuth_deg)).items():
                substance = by_name[stats["material"]].substance
                rows.append({"exemplar": stem, "part": name, "substance": substance} | stats)
            done += 1
            print(f"{stem}: {sum(r['exemplar'] == stem for r in rows)} parts", flush=True)
            if args.limit and done >= args.limit:
                break
        session.rollback()
    summary: dict[str, Any] = {"by_substance": {}, "by_material": {}}
    for key, label in (("substance", "by_substance"), ("material", "by_material")):
        groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
        for r in rows:
            groups[r[key]].append(r)
        print(f"{key}: parts, median luminance ratio ours/Blender, median Delta E, median dL*")
        for name, group in sorted(groups.items()):
            ratio = float(np.median([r["ratio"] for r in group]))
            de = float(np.median([r["delta_e"] for r in group]))
            dl = float(np.median([r["dL"] for r in group]))
            summary[label][name] = {"parts": len(group), "ratio": ratio, "delta_e": de, "dL": dl}
            print(f"  {name:32s} {len(group):3d}  {ratio:.3f}  {de:5.2f}  {dl:+5.2f}")
    out = results_dir(settings, "renderer_gap")
    out.mkdir(parents=True, exist_ok=True)
    name = f"results_turn{args.turn_deg:g}_az{args.azimuth_deg:g}.json"
    (out / name).write_text(json.dumps({"summary": summary, "parts": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
