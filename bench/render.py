"""Renderer benchmark: sweeps, part-ID methods, beauty renders against raw Mitsuba, cold vs warm JIT.

Run: ``.venv/bin/python bench/render.py [--quick]``. Prints a markdown table and writes
``bench/results/render.json``. The shape is a procedural ~50k-triangle, 9-part chair
(`photoshape_flow.render.testing.procedural_chair`), the views the paper's 456 (section 4.1), the
materials procedural textures (albedo, roughness, normal) under a procedural sky envmap.

Measured:
- sweeps: part IDs (+ silhouette) with and without the grey shaded pass, 456 views at 100^2 and 256^2;
- part-ID methods at 100^2 over 456 views: Mitsuba ``aov`` integrator (shape_index, one render per
  view, sensor moved via ``mi.traverse``), per-part constant albedo decoded from the ``albedo`` AOV,
  and the batched ray caster the Renderer uses, with their agreement;
- beauty: ``Renderer.beauty`` (scene build + render + tone mapping) against a plain ``mi.render``
  loop on the same loaded scene, at 256^2/64 spp and 500^2/256 spp;
- cold: first calls in a fresh process with an empty Dr.Jit kernel cache (``DRJIT_CACHE_DIR``
  pointed at a new folder), against the steady state.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "render.json"


# -- inputs -----------------------------------------------------------------------------------
def make_inputs(folder: Path) -> tuple[Any, list[Any], Any, list[Any]]:
    """Shape, materials (textured), envmap and the 456 cameras."""
    import cv2

    from photoshape_flow.render import EnvmapSpec, MaterialSpec
    from photoshape_flow.render.testing import paper_viewpoints, procedural_chair

    rng = np.random.default_rng(0)
    shape = procedural_chair(target_faces=50_000)
    materials = []
    for k, substance in enumerate(["wood", "fabric", "metal"]):
        noise = cv2.GaussianBlur(rng.random((512, 512)).astype(np.float32), (0, 0), 4 + 4 * k)
        noise = (noise - noise.min()) / (np.ptp(noise) + 1e-6)
        colour = np.array([[0.6, 0.4, 0.2], [0.3, 0.35, 0.6], [0.7, 0.7, 0.7]][k])
        albedo = (np.clip(noise[..., None] * 0.6 + 0.4, 0, 1) * colour * 255).astype(np.uint8)
        rough = (np.clip(0.3 + 0.4 * noise, 0, 1) * 255).astype(np.uint8)
        gy, gx = np.gradient(noise * 8)
        n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        normal = ((n * 0.5 + 0.5) * 255).astype(np.uint8)
        paths = {}
        for name, image in (("albedo", albedo), ("roughness", rough), ("normal", normal)):
            path = folder / f"{substance}_{name}.png"
            cv2.imwrite(str(path), image[..., ::-1] if image.ndim == 3 else image)
            paths[name] = path
        params = {"metallic": 1.0} if substance == "metal" else {}
        materials.append(MaterialSpec(substance, substance, maps=paths, params=params, scale=0.25))
    per_part = [materials[0], materials[0], *[materials[2]] * 4, materials[1], materials[1], materials[1]]
    # sky: bright upper hemisphere with a warm sun blob
    h, w = 128, 256
    theta = (np.arange(h) + 0.5) / h * math.pi
    sky = np.repeat(np.clip(np.cos(theta), 0.05, 1)[:, None, None] * [0.6, 0.7, 1.0], w, axis=1).astype(np.float32)
    sky[20:28, 40:52] = [40.0, 36.0, 30.0]
    env_path = folder / "sky.exr"
    import mitsuba as mi

    mi.Bitmap(np.ascontiguousarray(sky)).write(str(env_path))
    return shape, per_part, EnvmapSpec(env_path, scale=1.0, rotation=0.3), paper_viewpoints()


def timed(fn: Any, repeat: int = 1) -> tuple[float, Any]:
    """Median seconds of `repeat` calls and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


# -- part-ID methods --------------------------------------------------------------------------
def albedo_id_loop(renderer: Any, shape: Any, cameras: list[Any], size: int) -> np.ndarray:
    """Per-part constant albedo, decoded from the albedo AOV (R = low byte, G = high byte)."""
    mi = renderer.mi
    from photoshape_flow.render.scene import SceneOptions, build_scene, make_mesh, part_key

    scene_dict = build_scene(shape, None, None, cameras[0], SceneOptions(size=size, mode="aov"))
    scene_dict["integrator"] = {"type": "aov", "aovs": "alb:albedo"}
    for part in shape.parts:
        k = part.index
        colour = [(k & 255) / 255.0, (k >> 8) / 255.0, 0.0]
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}})
        scene_dict[part_key(k)] = make_mesh(part_key(k), part, bsdf=bsdf)
    scene = mi.load_dict(scene_dict)
    sensor = scene.sensors()[0]
    params = mi.traverse(sensor)
    out = np.zeros((len(cameras), size, size), np.uint16)
    for i, camera in enumerate(cameras):
        params["to_world"] = mi.ScalarTransform4f(camera.to_world().tolist())
        params.update()
        image = np.array(mi.render(scene, sensor=sensor, spp=1, seed=0))
        out[i] = np.round(image[..., 0] * 255) + 256 * np.round(image[..., 1] * 255)
    return out


def aov_id_loop(renderer: Any, shape: Any, cameras: list[Any], size: int) -> np.ndarray:
    return np.stack([renderer.part_ids(shape, camera, size, method="aov") for camera in cameras])


# -- beauty -----------------------------------------------------------------------------------
def beauty_pair(renderer: Any, shape: Any, materials: list[Any], envmap: Any, camera: Any, size: int, spp: int,
                repeat: int) -> dict[str, float]:
    """``Renderer.beauty`` against a plain ``mi.render`` loop on the same loaded scene, interleaved so
    that load drift on a shared machine hits both alike. Both are warmed first (scene cached, kernels
    compiled); the first, uncached call is reported as ``first_call_s``."""
    from photoshape_flow.render.scene import SceneOptions, build_scene

    mi = renderer.mi
    first, _ = timed(lambda: renderer.beauty(shape, materials, camera, envmap, size=size, spp=spp))
    options = SceneOptions(size=size, spp=spp, mode="beauty", max_depth=renderer.max_depth)
    build_s, scene = timed(lambda: mi.load_dict(build_scene(shape, materials, envmap, camera, options)))
    np.array(mi.render(scene, spp=spp, seed=0))
    ours, raw, saturated = [], [], 0.0
    for rep in range(repeat):
        seconds, result = timed(lambda r=rep: renderer.beauty(shape, materials, camera, envmap, size=size, spp=spp,
                                                               seed=r))
        ours.append(seconds)
        saturated = result.saturated_fraction
        seconds, _ = timed(lambda r=rep: np.array(mi.render(scene, spp=spp, seed=r)))
        raw.append(seconds)
    o, w = statistics.median(ours), statistics.median(raw)
    return {"ours_s": o, "raw_mitsuba_s": w, "ratio": o / w, "msamples_per_s": size * size * spp / w / 1e6,
            "first_call_s": first, "scene_build_s": build_s, "saturated_fraction": saturated}


# -- cold start (child process with an empty kernel cache) -----------------------------------
def cold_probe() -> dict[str, float]:
    from photoshape_flow.render.renderer import Renderer

    with tempfile.TemporaryDirectory() as folder:
        shape, materials, envmap, cameras = make_inputs(Path(folder))
        start = time.perf_counter()
        renderer = Renderer()
        out = {"startup_s": time.perf_counter() - start}
        out["sweep100_first_s"], _ = timed(lambda: renderer.sweep(shape, cameras, 100, shaded=True))
        out["sweep100_second_s"], _ = timed(lambda: renderer.sweep(shape, cameras, 100, shaded=True))
        out["beauty256_first_s"], _ = timed(lambda: renderer.beauty(shape, materials, cameras[40], envmap, size=256,
                                                                   spp=64))
        out["beauty256_second_s"], _ = timed(lambda: renderer.beauty(shape, materials, cameras[41], envmap, size=256,
                                                                    spp=64))
        # new shape objects with other part counts, as training renders meet them (96^2, 16 spp)
        from photoshape_flow.geometry.mesh import ShapeMesh

        news = []
        for k, count in enumerate((9, 8, 6, 5, 7, 3)):
            part = ShapeMesh(parts=shape.parts[:count])
            seconds, _ = timed(lambda p=part, k=k: renderer.beauty(p, materials[: len(p.parts)], cameras[k * 37],
                                                                   envmap, size=96, spp=16, seed=k))
            news.append(seconds)
        out["beauty96_new_shapes_s"] = news
        out["beauty96_same_shape_s"], _ = timed(lambda: renderer.beauty(part, materials[: len(part.parts)], cameras[1],
                                                                       envmap, size=96, spp=16), 3)
    return out


def run_cold() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, DRJIT_CACHE_DIR=cache)
        proc = subprocess.run([sys.executable, __file__, "--cold-probe"], env=env, capture_output=True, text=True,
                              check=True, timeout=900)
    return json.loads(proc.stdout.strip().splitlines()[-1])


# -- main -------------------------------------------------------------------------------------
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, no 500^2/256 spp beauty")
    parser.add_argument("--cold-probe", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    if args.cold_probe:
        sys.stdout.write(json.dumps(cold_probe()) + "\n")
        return

    from photoshape_flow.render.renderer import Renderer

    cold = run_cold()
    renderer = Renderer()
    results: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                           "threads": renderer.dr.thread_count(),
                                           "loadavg_start": os.getloadavg()[0]}, "cold": cold}
    with tempfile.TemporaryDirectory() as folder:
        shape, materials, envmap, cameras = make_inputs(Path(folder))
        results["shape"] = {"faces": shape.num_faces, "parts": len(shape.parts), "views": len(cameras)}
        repeat = 1 if args.quick else 3

        sweeps = {}
        for size in (100, 256):
            for shaded in (False, True):
                renderer.sweep(shape, cameras[:8], size, shaded=shaded)  # warm
                seconds, _ = timed(lambda s=size, sh=shaded: renderer.sweep(shape, cameras, s, shaded=sh), repeat)
                name = f"{size}{'_shaded' if shaded else ''}"
                sweeps[name] = {"seconds": seconds, "views_per_s": len(cameras) / seconds}
        results["sweep"] = sweeps

        rays = renderer.sweep(shape, cameras, 100, shaded=False).part_ids
        methods = {}
        for name, fn in (("mitsuba_aov_shape_index", aov_id_loop), ("albedo_aov", albedo_id_loop)):
            fn(renderer, shape, cameras[:4], 100)  # warm
            seconds, ids = timed(lambda f=fn: f(renderer, shape, cameras, 100))
            methods[name] = {"seconds": seconds, "views_per_s": len(cameras) / seconds,
                             "agreement_with_rays": float((ids == rays).mean())}
        methods["batched_rays"] = {"seconds": sweeps["100"]["seconds"], "views_per_s": sweeps["100"]["views_per_s"],
                                   "agreement_with_rays": 1.0}
        results["part_id_methods"] = methods

        beauty = {}
        configs = [(256, 64, 3)] + ([] if args.quick else [(500, 256, 2)])
        camera = cameras[40]
        for size, spp, reps in configs:
            beauty[f"{size}x{size}@{spp}spp"] = beauty_pair(renderer, shape, materials, envmap, camera, size, spp, reps)
        results["beauty"] = beauty
    results["machine"]["loadavg_end"] = os.getloadavg()[0]

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    print_table(results)


def print_table(r: dict[str, Any]) -> None:
    lines = [f"Renderer benchmark: {r['shape']['faces']} triangles, {r['shape']['parts']} parts, "
             f"{r['shape']['views']} views, {r['machine']['threads']} threads, "
             f"load {r['machine']['loadavg_start']:.1f}->{r['machine']['loadavg_end']:.1f}", "",
             "| measurement | value |", "|---|---|"]
    for name, s in r["sweep"].items():
        lines.append(f"| sweep {name} (456 views) | {s['seconds']:.2f} s, {s['views_per_s']:.0f} views/s |")
    for name, m in r["part_id_methods"].items():
        lines.append(f"| part IDs 100^2 via {name} | {m['seconds']:.2f} s, {m['views_per_s']:.0f} views/s, "
                     f"agreement {m['agreement_with_rays']:.4f} |")
    for name, b in r["beauty"].items():
        lines.append(f"| beauty {name} | ours {b['ours_s']:.2f} s, raw Mitsuba {b['raw_mitsuba_s']:.2f} s, "
                     f"ratio {b['ratio']:.3f}, {b['msamples_per_s']:.1f} Msamples/s; "
                     f"first call {b['first_call_s']:.2f} s, scene build {b['scene_build_s']:.2f} s |")
    c = r["cold"]
    lines.append(f"| cold: sweep 100^2 first / second | {c['sweep100_first_s']:.2f} s / "
                 f"{c['sweep100_second_s']:.2f} s |")
    lines.append(f"| cold: beauty 256^2@64 first / second | {c['beauty256_first_s']:.2f} s / "
                 f"{c['beauty256_second_s']:.2f} s |")
    if "beauty96_new_shapes_s" in c:
        news = c["beauty96_new_shapes_s"]
        lines.append(f"| cold: beauty 96^2@16 of {len(news)} new shapes (3-9 parts) / same shape again | "
                     f"mean {statistics.mean(news):.3f} s (after the first {statistics.mean(news[1:]):.3f} s) / "
                     f"{c['beauty96_same_shape_s']:.3f} s |")
    sys.stdout.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
