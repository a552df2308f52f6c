"""Refinement benchmark (`fit.refine`): seconds per refined pair at the medium profile, and what it recovers.

Run: ``.venv/bin/python bench/refine.py [--pairs 4] [--empty-cache]``. Prints a table and writes
``bench/results/refine.json``.

A generated scene, no demo needed: the 9-part procedural chair of bench/render.py (~50k triangles)
with its three textured materials (albedo, roughness and normal maps) under its sky envmap. Each
"photo" is the chair at a product-photo camera with every part's material adjusted by a random
known `Refinement` (tint 0.75-1.35 per channel, roughness x0.7-1.4, UV scale 0.7/1/1.4),
path-traced at 128 px and 64 spp, exposed by 0.8, its part map shifted by one pixel (alignment is
never exact). Refinement starts from the unadjusted materials with the medium profile's settings
(`FitConfig`: the tint solved like for like at the fit's 128 px frame; the UV search at `refine_spp`
4 and the Adam steps on the roughness at a 64 px frame only when asked, ``--set uv=1 --set
iterations=8``, as `fit.refine_uv` / `fit.refine_iterations` do) and is timed per pair; making the
photos is not (subtracted from the process's time too).

The probe runs in a fresh process (`--probe`), so the first pair pays the imports, Mitsuba's start
and the kernels' compilation: with the Dr.Jit kernel cache on disk as a worker finds it, and with
``--empty-cache`` also from an empty one (``DRJIT_CACHE_DIR`` pointed at a new folder).
Reported per pair: seconds, the median absolute tint error over parts before (1 - true tint) and
after, the roughness-scale error, UV scales right, and the loss ratio after/before.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

START = time.perf_counter()
RESULTS = Path(__file__).resolve().parent / "results"


def _bench_render() -> object:
    """bench/render.py as a module (its `make_inputs`: the chair, its materials and sky)."""
    spec = importlib.util.spec_from_file_location("bench_render", Path(__file__).with_name("render.py"))
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def overrides(items: list[str]) -> dict[str, float]:
    """NAME=VALUE pairs: whole numbers as int (iterations, uv as 0/1), others as float."""
    return {name: int(value) if value.lstrip("-").isdigit() else float(value)
            for name, value in (item.split("=", 1) for item in items)}


def probe(pairs: int, settings_overrides: dict[str, float] | None = None, uv_spp: int | None = None) -> dict:
    from dataclasses import replace

    import numpy as np

    from photoshape_flow.fit.refine import refine_parts
    from photoshape_flow.fit.scene import FitScene, FrameRenderer
    from photoshape_flow.fitting.refine import refine_settings
    from photoshape_flow.profiles import PROFILES
    from photoshape_flow.render import Refinement
    from photoshape_flow.render.renderer import Renderer
    from photoshape_flow.render.specs import linear_to_srgb

    cfg = PROFILES["medium"].fit
    exposure = 0.8
    rng = np.random.default_rng(7)
    out: dict = {"pairs": [], "import_s": time.perf_counter() - START}
    with tempfile.TemporaryDirectory() as folder:
        shape, materials, envmap, cameras = _bench_render().make_inputs(Path(folder))  # type: ignore[attr-defined]
        renderer = Renderer()
        for k in range(pairs):
            photo_started = time.perf_counter()
            camera = cameras[(37 + 101 * k) % len(cameras)]
            truth = [Refinement(tuple(float(x) for x in rng.uniform(0.75, 1.35, 3)), float(rng.uniform(0.7, 1.4)),
                                float(rng.choice([0.7, 1.0, 1.4])), 0.0) for _ in shape.parts]
            photo_frame = FrameRenderer(renderer, cfg.size, 64)
            linear = photo_frame.render(shape, [replace(m, refinement=t) for m, t in zip(materials, truth,
                                                                                          strict=True)],
                                        camera, envmap)
            photo = (linear_to_srgb(exposure * linear) * 255 + 0.5).astype(np.uint8)
            ids = photo_frame.part_ids(shape, camera)
            scene = FitScene.from_photo(shape, camera, photo, np.roll(ids, 1, axis=1),
                                        [p.index for p in shape.parts], cfg.erode, blur=cfg.blur,
                                        foreground=ids > 0)
            photo_s = time.perf_counter() - photo_started
            settings = refine_settings(cfg)
            settings = replace(settings, **(settings_overrides or {}))
            started = time.perf_counter()
            result = refine_parts(FrameRenderer(renderer, cfg.refine_size, cfg.refine_spp), scene, materials,
                                  sorted(scene.masks), envmap, exposure, settings,
                                  uv_frame=FrameRenderer(renderer, cfg.size, uv_spp or cfg.refine_spp))
            seconds = time.perf_counter() - started
            by_index = {p.index: t for p, t in zip(shape.parts, truth, strict=True)}
            tint_before = [abs(1.0 - t) for i in result for t in by_index[i].tint]
            tint_after = [abs(a - t) for i, r in result.items()
                          for a, t in zip(r.refinement.tint, by_index[i].tint, strict=True)]
            rough_after = [abs(r.refinement.roughness_scale - by_index[i].roughness_scale) for i, r in result.items()]
            out["pairs"].append({
                "seconds": seconds, "photo_s": photo_s, "parts": len(result),
                "since_start_s": time.perf_counter() - START - sum(p["photo_s"] for p in out["pairs"]) - photo_s,
                "tint_error_before": float(np.median(tint_before)), "tint_error_after": float(np.median(tint_after)),
                "roughness_error_before": float(np.median([abs(1 - by_index[i].roughness_scale) for i in result])),
                "roughness_error_after": float(np.median(rough_after)),
                "uv_scale_right": float(np.mean([r.refinement.uv_scale == by_index[i].uv_scale
                                                 for i, r in result.items()])),
                "loss_ratio": float(np.median([r.loss_after / max(r.loss_before, 1e-12) for r in result.values()])),
            })
    out["process_s"] = time.perf_counter() - START
    return out


def run_probe(pairs: int, empty_cache: bool, settings: list[str], uv_spp: int | None = None) -> dict:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as cache:
        if empty_cache:
            env["DRJIT_CACHE_DIR"] = cache
        extra = [arg for item in settings for arg in ("--set", item)] + (
            ["--uv-spp", str(uv_spp)] if uv_spp else [])
        proc = subprocess.run([sys.executable, __file__, "--probe", "--pairs", str(pairs), *extra], env=env,
                              capture_output=True, text=True, check=True, timeout=1800)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--empty-cache", action="store_true", help="also run with an empty Dr.Jit kernel cache")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a RefineSettings number (e.g. std_weight=0), repeatable")
    parser.add_argument("--uv-spp", type=int, default=None, help="spp of the UV search (default: fit.refine_spp)")
    parser.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.probe:
        print(json.dumps(probe(args.pairs, overrides(args.set), args.uv_spp)))
        return
    runs = {"warm kernel cache": run_probe(args.pairs, False, args.set, args.uv_spp)}
    if args.empty_cache:
        runs["empty kernel cache"] = run_probe(args.pairs, True, args.set, args.uv_spp)
    record = {"settings": overrides(args.set),
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": platform.platform(),
              "cpus": os.cpu_count(), "load_average": os.getloadavg(), "runs": runs}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "refine.json").write_text(json.dumps(record, indent=1))
    print("| run | pairs | first pair s (process start to done) | later pairs s (mean) | per pair s, process "
          "amortised | tint err before -> after | roughness err before -> after | UV scale right "
          "| loss after/before |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, run in runs.items():
        pairs = run["pairs"]
        later = [p["seconds"] for p in pairs[1:]] or [math.nan]

        def med(key: str, items: list = pairs) -> float:
            values = sorted(p[key] for p in items)
            return values[len(values) // 2]

        amortised = (run["process_s"] - sum(p["photo_s"] for p in pairs)) / len(pairs)
        print(f"| {name} | {len(pairs)} | {pairs[0]['since_start_s']:.1f} | {sum(later) / len(later):.2f} | "
              f"{amortised:.2f} | {med('tint_error_before'):.3f} -> {med('tint_error_after'):.3f} | "
              f"{med('roughness_error_before'):.3f} -> {med('roughness_error_after'):.3f} | "
              f"{sum(p['uv_scale_right'] for p in pairs) / len(pairs):.2f} | {med('loss_ratio'):.3f} |")
    print(f"load average {os.getloadavg()}")


if __name__ == "__main__":
    main()
