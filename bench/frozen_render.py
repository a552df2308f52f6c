"""Frozen beauty renders (`dr.freeze` around `mi.render` on the beauty pool): time and faithfulness.

Run: ``.venv/bin/python bench/frozen_render.py [--shapes N]``. Prints a markdown table and writes
``bench/results/frozen_render.json``.

Why: a fit-size render (9 parts, 120 px, 8 spp) spends about half its time tracing the path
tracer (`render.pool`'s module doc); `dr.freeze` records the kernels once and replays them on the
scene's new data. Replays are only worth having if they render what a traced render of the same
scene renders, so every frozen render here is compared with a traced render of the same prepared
scene (`mi.render` on the pool's scene right after it).

The generated sequence is the fit's pattern per pair (`fit.scene`): a shape is rendered `LIGHTS`
times with the same materials under envmap rotations (the lighting search), then `CANDIDATES` times
with other materials per part (the candidate slots: other textures, texture sizes and UV scales).
Three recording keys are measured: the pool's geometry upload only (Embree's scene changes only
then), the geometry or any part's UVs (a material's scale rewrites the part's UVs), and the pool's
own (`BeautyPool.render`: any upload of meshes, UVs, textures or envmap pixels re-records).

``--fit-data-root DIR`` checks the fit stage's own renders instead (on a copy of a data root that
went through inference): that is where replays went wrong. Measured 2026-11-28 (Dr.Jit 1.5.0,
Mitsuba 3.9.1, small demo): the generated sequence replays faithfully (0 of 132 renders differ,
worst 1.8e-7) at 56-72 ms against 88-92 ms traced, but of the fit stage's first 600 renders 90
differ from their traced render (some not finite) when keyed on geometry, 1 (by 2.8, the same
render at both calibration blurs) when UV rewrites re-record too, and 0 of 900 (worst 9.5e-7)
when any texture or envmap upload re-records as well: `render.pool`'s key (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "frozen_render.json"
SIZE, SPP = 120, 8  # the small profile's fit frame (96 px x `fit.scene.OVERSAMPLE`) and spp
LIGHTS, CANDIDATES = 12, 10  # renders per shape: the lighting search, then the candidate slots


def make_materials(folder: Path, rng: np.random.Generator) -> list[Any]:
    """Textured materials (albedo, roughness, normal at 64-256 px, scales 0.1-0.4) and constant ones."""
    import cv2

    from photoshape_flow.render import MaterialSpec

    out = []
    for k in range(8):
        side = (64, 128, 256)[k % 3]
        noise = cv2.GaussianBlur(rng.random((side, side)).astype(np.float32), (0, 0), 2 + k)
        noise = (noise - noise.min()) / (np.ptp(noise) + 1e-6)
        albedo = (np.clip(noise[..., None] * 0.6 + 0.4, 0, 1) * rng.uniform(0.2, 0.9, 3) * 255).astype(np.uint8)
        gy, gx = np.gradient(noise * 8)
        n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        paths = {}
        for name, image in (("albedo", albedo), ("roughness", (noise * 200 + 30).astype(np.uint8)),
                            ("normal", ((n * 0.5 + 0.5) * 255).astype(np.uint8))):
            paths[name] = folder / f"m{k}_{name}.png"
            cv2.imwrite(str(paths[name]), image[..., ::-1] if image.ndim == 3 else image)
        out.append(MaterialSpec(f"t{k}", maps=paths, params={"metallic": float(k % 4 == 3)}, scale=0.1 + 0.05 * k))
    for k in range(6):
        out.append(MaterialSpec(f"c{k}", params={"albedo": list(rng.uniform(0.05, 0.95, 3)),
                                                 "roughness": float(rng.uniform(0.1, 0.9)),
                                                 "metallic": float(k == 5)}))
    return out


def make_envmaps(folder: Path, rng: np.random.Generator) -> list[Any]:
    import mitsuba as mi

    from photoshape_flow.render import EnvmapSpec

    out = []
    h, w = 128, 256
    theta = (np.arange(h) + 0.5) / h * math.pi
    for k in range(3):
        sky = np.repeat(np.clip(np.cos(theta), 0.05, 1)[:, None, None] * rng.uniform(0.5, 1.0, 3), w, axis=1)
        sky = sky.astype(np.float32)
        sky[16 + 8 * k:24 + 8 * k, 40 * k:40 * k + 16] = 30.0
        path = folder / f"sky{k}.exr"
        mi.Bitmap(np.ascontiguousarray(sky)).write(str(path))
        out.append(EnvmapSpec(path))
    return out


def sequence(shapes: int, materials: list[Any], envmaps: list[Any], rng: np.random.Generator) -> list[dict]:
    """The renders, in order: per shape the lighting renders, then the candidate renders."""
    from dataclasses import replace

    from photoshape_flow.render import Camera
    from photoshape_flow.render.testing import procedural_chair

    out = []
    for s in range(shapes):
        shape = procedural_chair(target_faces=3000 + 500 * s)
        parts = len(shape.parts)
        camera = Camera(float(rng.uniform(0, 2 * math.pi)), 0.3, 2.2, 40.0)
        rank1 = [materials[int(i)] for i in rng.integers(0, len(materials), parts)]
        for k in range(LIGHTS):
            env = replace(envmaps[k % len(envmaps)], rotation=2 * math.pi * (k // len(envmaps)) / 4)
            out.append({"shape": s, "geometry": shape, "materials": rank1, "camera": camera, "envmap": env})
        for _ in range(CANDIDATES):
            chosen = [materials[int(i)] for i in rng.integers(0, len(materials), parts)]
            out.append({"shape": s, "geometry": shape, "materials": chosen, "camera": camera,
                        "envmap": out[-1]["envmap"]})
    return out


def run(items: list[dict], mode: str, check: bool, limit: int = 4) -> dict[str, Any]:
    """Render `items` traced (``mode="traced"``), as `BeautyPool.render` does (``pool``), or frozen under a
    key of this bench (``geometry`` or ``geometry+uv``);
    with `check`, compare each frozen render with a traced render of the same scene."""
    import drjit as dr
    import mitsuba as mi

    from photoshape_flow.render.factory import default_renderer
    from photoshape_flow.render.pool import _frozen_render, beauty_pool
    from photoshape_flow.render.scene import SceneOptions

    renderer = default_renderer()

    @dr.freeze(limit=limit, warn_after=1 << 30)
    def frozen(scene: Any, key: tuple) -> Any:
        return mi.render(scene, spp=SPP, seed=0)

    options = SceneOptions(size=SIZE, spp=SPP, max_depth=renderer.max_depth,
                           max_texture_size=renderer.max_texture_size)
    seconds, mismatched, worst = 0.0, 0, 0.0
    for item in items:
        materials = renderer.resolve_materials(item["geometry"], item["materials"])
        pool = beauty_pool(len(materials), renderer.max_depth, renderer.envmap_resolution)
        pool.prepare(item["geometry"], materials, item["envmap"], item["camera"], options)
        uvs = tuple(m.scale for m in materials) if mode == "geometry+uv" else ()
        start = time.perf_counter()
        if mode == "traced":
            image = np.array(mi.render(pool.scene, spp=SPP, seed=0), dtype=np.float32)
        elif mode == "pool":
            image = pool.render(SPP, 0)
        else:
            image = np.array(frozen(pool.scene, (item["shape"], uvs)), dtype=np.float32)
        seconds += time.perf_counter() - start
        if check and mode != "traced":
            traced = np.array(mi.render(pool.scene, spp=SPP, seed=0), dtype=np.float32)
            error = float(np.abs(image - traced).max()) if np.isfinite(image).all() else math.inf
            worst = max(worst, error)
            mismatched += error > 1e-4 * max(1.0, float(traced.max()))
    out = {"mode": mode, "renders": len(items), "ms_per_render": round(1000 * seconds / len(items), 1)}
    if check and mode != "traced":
        out.update(mismatched=mismatched, worst_abs_error=worst,
                   recordings=int((_frozen_render() if mode == "pool" else frozen).n_recordings))
    return out


class _Enough(BaseException):
    """Stops the fit stage once enough renders are checked (not an Exception: the stage would go on)."""


def check_fit_stage(data_root: Path, renders: int) -> dict[str, Any]:
    """Run the fit stage on `data_root` (a copy: it writes fit rows) and check each of its frozen
    renders (`BeautyPool.render`, the pool's own key) against a traced render of the same scene;
    stop after `renders` renders."""
    import os

    import mitsuba as mi

    from photoshape_flow.render import pool as pool_module

    os.environ["PHOTOSHAPE_DATA_ROOT"] = str(data_root)
    state = {"renders": 0, "mismatched": 0, "worst": 0.0}
    frozen_render = pool_module.BeautyPool.render

    def checked(self: Any, spp: int, seed: int, record: bool = True) -> np.ndarray:
        image = frozen_render(self, spp, seed, record)
        traced = np.array(mi.render(self.scene, spp=int(spp), seed=int(seed)), dtype=np.float32)
        error = float(np.abs(image - traced).max()) if np.isfinite(image).all() else math.inf
        state["renders"] += 1
        state["worst"] = max(state["worst"], error)
        state["mismatched"] += error > 1e-4 * max(1.0, float(traced.max()))
        if state["renders"] >= renders:
            raise _Enough
        return image

    pool_module.BeautyPool.render = checked
    from photoshape_flow.cli import main as cli

    sys.argv = ["photoshape", "run", "fit", "--profile", "small"]
    try:
        cli()
    except (_Enough, SystemExit):
        pass
    return {"mode": "fit stage, render.pool's key", "renders": state["renders"], "mismatched": state["mismatched"],
            "worst_abs_error": state["worst"], "recordings": int(pool_module._frozen_render().n_recordings)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=int, default=6)
    parser.add_argument("--limit", type=int, default=4, help="recordings `dr.freeze` keeps (generated sequence)")
    parser.add_argument("--fit-data-root", type=Path, help="a copy of a data root that went through "
                        "inference (the small demo's): check the fit stage's own renders instead")
    parser.add_argument("--renders", type=int, default=900, help="with --fit-data-root: renders to check")
    args = parser.parse_args()
    if args.fit_data_root is not None:
        print(json.dumps(check_fit_stage(args.fit_data_root, args.renders)))
        return
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        items = sequence(args.shapes, make_materials(folder, rng), make_envmaps(folder, rng), rng)
        run(items[:LIGHTS + CANDIDATES], "traced", check=False)  # warm the compiled kernels
        rows = [run(items, "traced", check=False), run(items, "geometry", False, args.limit),
                run(items, "geometry+uv", False, args.limit),
                run(items, "geometry", True, args.limit), run(items, "geometry+uv", True, args.limit),
                run(items, "pool", False), run(items, "pool", True)]
    report = {"machine": platform.processor() or platform.machine(), "python": sys.version.split()[0],
              "date": time.strftime("%Y-%m-%d %H:%M"), "size": SIZE, "spp": SPP,
              "limit": args.limit, "rows": rows}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2))
    print("| mode | renders | ms per render | mismatched | worst abs error |")
    print("|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['mode']}{' (checked)' if 'mismatched' in row else ''} | {row['renders']} | "
              f"{row['ms_per_render']} | {row.get('mismatched', '-')} | {row.get('worst_abs_error', '-')} |")


if __name__ == "__main__":
    main()
