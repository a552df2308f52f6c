"""Build the second evaluation world: `python -m experiments.second_world.build --out DIR --seed N`.

Layout of DIR:
    collection/shapes      subset .sh3f catalogs + shared models      -> photoshape ingest shapes
    collection/materials   real scans + demo SVBRDFs                  -> photoshape ingest materials
    collection/envmaps     the demo's studio envmaps                  -> photoshape ingest envmaps
    exemplars/*.jpg        Blender Cycles renders over white (JPEG)   -> photoshape ingest exemplars
                                                                         --source second-world
    masks/*.png            per-pixel part index (0 = background)
    groundtruth.json       docs/evaluation.md format, version 2       -> photoshape eval --groundtruth
    heldout_materials/     the open-library variants (never ingested)
    LICENSES/              every input's licence; world.json: seed, commit, counts, build time
    work/                  prepared meshes, scene descriptions, raw renders (resumable cache)

Blender is needed only here, and only as a program (`blender -b -P blender_render.py`); without it
the build says how to install it and stops before doing any work.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2

from experiments.second_world import licenses, materials, plan, scenes, shapes
from photoshape_flow.demo.envmaps import studio_specs, write_studio

REPO = Path(__file__).resolve().parents[2]
BLENDER_SCRIPT = Path(__file__).with_name("blender_render.py")
INSTALL_HINT = ("Blender not found. Install it (Debian/Ubuntu: `apt-get install -y blender`, 3.4.1 was used) "
                "or pass --blender /path/to/blender. Nothing was built.")
STUDIOS = 4
BATCH = 8  # scenes per Blender process: amortises its start-up, bounds what one crash costs


def find_blender(given: str | None) -> str | None:
    if given:
        return given if Path(given).is_file() else None
    return shutil.which("blender")


def git_commit() -> str:
    """The last commit that changed the generator (this folder but its README), "+dirty" when the
    working tree changes it: the world's identity, stable across commits elsewhere in the repo."""
    paths = ["--", "experiments/second_world", ":!experiments/second_world/README.md"]
    try:
        head = subprocess.run(["git", "-C", str(REPO), "log", "-1", "--format=%H", *paths], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", *paths], capture_output=True,
                               text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return (head or "unknown") + ("+dirty" if dirty else "")


def run_blender(blender: str, scene_paths: list[Path], threads: int) -> list[str]:
    """Render the scenes in batches; returns one line per scene that failed."""
    failed: list[str] = []
    for start in range(0, len(scene_paths), BATCH):
        batch = scene_paths[start:start + BATCH]
        cmd = [blender, "-b", "--factory-startup", "-t", str(threads), "-P", str(BLENDER_SCRIPT), "--",
               *map(str, batch)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        done = {line.split(" ", 1)[1] for line in proc.stdout.splitlines() if line.startswith("SECOND_WORLD_DONE ")}
        failed += [line for line in proc.stdout.splitlines() if line.startswith("SECOND_WORLD_FAILED ")]
        lost = [str(p) for p in batch if str(p) not in done and not any(str(p) in f for f in failed)]
        if lost:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            failed += [f"{p}: Blender exited {proc.returncode} ({' / '.join(tail)})" for p in lost]
        print(f"rendered {min(start + BATCH, len(scene_paths))}/{len(scene_paths)}", flush=True)
    return failed


def build(out: Path, seed: int, count: int, size: int, samples: int, threads: int, blender: str,
          data: Path) -> int:
    started = time.time()
    work = out / "work"
    coll = out / "collection"
    print(f"second world -> {out} (seed {seed}, {count} exemplars, {size} px, {samples} spp)", flush=True)

    # materials: the library is ingested, variants are not
    library = materials.write_library(data / "materials", coll / "materials")
    studios = studio_specs(seed, STUDIOS, "studio")
    for spec in studios:
        write_studio(coll / "envmaps" / f"{spec.name}.hdr", spec)
    hdris = sorted((data / "envmaps").glob("*.hdr"))

    # shapes: the project's importer, cached per shape
    items, problems = shapes.discover_seating(data / "models")
    infos: list[plan.ShapeInfo] = []
    for item in items:
        try:
            infos.append(shapes.prepare_item(item, work / "meshes"))
        except Exception as exc:  # one bad model costs one shape
            problems.append(f"{item.label}: {type(exc).__name__}: {exc}; skipped")
    for line in problems:
        print(line)
    split = plan.split_shapes(seed, infos)
    plans = plan.plan_world(seed, split, [a.library() for a in library], [h.name for h in hdris], count)
    issues = plan.check_world(plans)
    if issues:
        print("the plan misses the world's requirements: " + "; ".join(issues))
        return 1

    by_key = {(i.source, i.source_id): i for i in items}
    shapes.write_collection_shapes(items, list(split.collection), coll / "shapes", data / "models")
    found = shapes.collection_keys(coll / "shapes")
    wanted = {(s.source, s.source_id) for s in split.collection}
    if found != wanted:
        print(f"collection/shapes does not ingest as planned: missing {sorted(wanted - found)[:5]}, "
              f"extra {sorted(found - wanted)[:5]}")
        return 1

    # variants (open library) and every material's mean albedo
    assets = {a.name: a for a in library}
    for p in plans:
        for part in p.parts.values():
            if part.variant is not None and part.variant.name not in assets:
                assets[part.variant.name] = materials.write_variant(assets[part.material], part.variant,
                                                                    out / "heldout_materials")
    albedo_lab = {name: materials.mean_lab(materials.read_rgb(a.albedo)) for name, a in assets.items()}

    # scene descriptions, then Blender
    means = {h.name: scenes.hdri_mean(h) for h in hdris}
    hdri_paths = {h.name: h for h in hdris}
    descs: dict[str, dict] = {}
    todo: list[Path] = []
    for p in plans:
        parts = shapes.part_records(work / "meshes", p.shape)
        outputs = {"beauty": work / "renders" / f"{p.stem}.png", "mask": work / "renders" / f"{p.stem}_mask.png"}
        desc = scenes.scene_description(p, parts, assets, work / "meshes" / f"{p.shape.key}.obj",
                                        hdri_paths[p.envmap["name"]], means[p.envmap["name"]], outputs, size, samples)
        descs[p.stem] = desc
        path = work / "scenes" / f"{p.stem}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(desc, indent=1)
        fresh = path.is_file() and path.read_text() == text and all(o.is_file() for o in outputs.values())
        if not fresh:
            path.write_text(text)
            for o in outputs.values():
                o.unlink(missing_ok=True)
            todo.append(path)
    (work / "renders").mkdir(parents=True, exist_ok=True)
    print(f"{len(todo)} of {len(plans)} scenes to render", flush=True)
    failed = run_blender(blender, todo, threads)
    for line in failed:
        print(line)

    # photos, masks, ground truth
    entries = []
    for p in plans:
        desc = descs[p.stem]
        parts = shapes.part_records(work / "meshes", p.shape)
        try:
            photo = scenes.finish_photo(scenes.read_render(Path(desc["outputs"]["beauty"])), p.jpeg_quality)
            mask = scenes.mask_from_render(Path(desc["outputs"]["mask"]), len(parts))
        except (FileNotFoundError, ValueError) as exc:
            print(f"{p.stem}: {exc}; left out of the world")
            continue
        (out / "exemplars").mkdir(parents=True, exist_ok=True)
        (out / "exemplars" / f"{p.stem}.jpg").write_bytes(photo)
        (out / "masks").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / "masks" / f"{p.stem}.png"), mask)
        entries.append(scenes.groundtruth_entry(p, parts, assets, albedo_lab, desc, p.envmap["name"],
                                                f"masks/{p.stem}.png"))
    kept = [p for p in plans if any(e["source_id"] == p.stem for e in entries)]
    counts = plan.world_counts(kept)
    counts["shapes_ingested"] = len(split.collection)
    counts["shapes_held_out"] = len(split.heldout)
    counts["materials_ingested"] = len(library)
    counts["material_variants"] = len(assets) - len(library)
    info = {"seed": seed, "generator_commit": git_commit(), "blender": blender, "resolution": size,
            "samples": samples, "build_seconds": round(time.time() - started, 1), "counts": counts,
            "exemplar_hdris": [h.name for h in hdris], "collection_envmaps": [s.name for s in studios],
            "failed": failed}
    truth = {"format": "photoshape-groundtruth", "version": 2, "exemplars": entries,
             "world": {k: info[k] for k in ("seed", "generator_commit", "counts")},
             "notes": ("parts.material is the ingested library material; on the open-library share it is the "
                       "parent of the variant the photo shows (parts.shown_material, parts.variant). "
                       "lighting.envmap/rotation/scale light the exemplar as EnvmapSpec(path, scale, rotation) "
                       "would (project convention, radians about +y); rotation_blender_z is Blender's own.")}
    (out / "groundtruth.json").write_text(json.dumps(truth, indent=1) + "\n")
    licenses.write_licenses(out / "LICENSES", by_key, list(split.collection), kept, list(assets.values()),
                            [h.name for h in hdris], [s.name for s in studios], data / "licenses")
    info["build_seconds"] = round(time.time() - started, 1)
    (out / "world.json").write_text(json.dumps(info, indent=1) + "\n")
    print(json.dumps(info["counts"], indent=1))
    print(f"built in {info['build_seconds']} s; ground truth: {out / 'groundtruth.json'}")
    return 0 if not failed else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.second_world.build",
                                     description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="the world's folder (outside git)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--exemplars", type=int, default=56)
    parser.add_argument("--size", type=int, default=320, help="exemplar size in pixels (square)")
    parser.add_argument("--samples", type=int, default=64, help="Cycles samples per pixel")
    parser.add_argument("--threads", type=int, default=1, help="Blender render threads (-t)")
    parser.add_argument("--blender", default=None, help="the blender program (default: blender on PATH)")
    default_data = Path(os.environ.get("PHOTOSHAPE_SHARED_DATA", REPO.parent / "shared" / "data"))
    parser.add_argument("--data", type=Path, default=default_data,
                        help="shared/data (models, materials, envmaps, licenses)")
    args = parser.parse_args(argv)
    blender = find_blender(args.blender)
    if blender is None:
        print(INSTALL_HINT, file=sys.stderr)
        return 2
    if not (args.data / "materials").is_dir():
        print(f"{args.data}: not the shared data folder (no materials/); pass --data", file=sys.stderr)
        return 2
    return build(args.out, args.seed, args.exemplars, args.size, args.samples, args.threads, blender, args.data)


if __name__ == "__main__":
    sys.exit(main())
