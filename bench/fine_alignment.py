"""Fine alignment benchmark: flow-method choice by measurement, and seconds per pair.

Synthetic 3-D pairs with exact ground truth (no demo data needed): a demo furniture shape is
rendered (path-traced, built-in materials, white sky, sensor noise) from a product-photo camera
(demo.exemplars.sample_camera: fov 50-60, distance framing the object); that photo, tight-cropped
like ingest crops, is the exemplar, and its exact part-ID render is the ground truth. The pair's
camera is what coarse alignment can give at best plus retrieval noise: the nearest of the paper's
456 views (distance 2, fov 50) to the true direction jittered by N(0, `--jitter` deg). So the
coarse part map differs from the truth by the view quantisation, the retrieval error and the
perspective (distance / fov) difference. `--similar K` adds K pairs whose exemplar shows a
perturbed design (no part ground truth: silhouette IoU only).

For each flow candidate: part-label accuracy (over ground-truth foreground) after coarse, flow
and CRF, silhouette IoU, and seconds; then the timing of the whole step (render + flow + CRF) at
the working resolution with the default parameters. Writes bench/results/fine_alignment.json.

`--demo SIZE` also runs the real chain on the demo collection in a scratch data root (generate_demo,
ingest shapes and exemplars, coarse alignment, then run_fine_alignment once per flow candidate as
method "flow-crf:<candidate>") and scores it with evaluate_fine_alignment against groundtruth.json.

    .venv/bin/python bench/fine_alignment.py [--pairs 12] [--similar 4] [--size 320] [--demo small]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from photoshape_flow.align.crf import crf_refine, pydensecrf_available
from photoshape_flow.align.fine import FineParams, align_pair, part_label_accuracy, silhouette_iou
from photoshape_flow.align.flow import FLOW_METHODS, flow_warp
from photoshape_flow.align.partmap import crop_square, exemplar_at, render_coarse_part_map, resize_labels, square_box

RESULTS = Path(__file__).resolve().parent / "results"


def nearest_view(views: list, azimuth: float, elevation: float):  # type: ignore[no-untyped-def]
    """The grid camera whose viewing direction is closest to (azimuth, elevation)."""

    def direction(az: float, el: float) -> np.ndarray:
        return np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])

    target = direction(azimuth, elevation)
    return max(views, key=lambda c: float(direction(c.azimuth, c.elevation) @ target))


def make_pairs(renderer, n_exact: int, n_similar: int, size: int, jitter_deg: float, seed: int) -> list[dict]:  # type: ignore[no-untyped-def]
    from photoshape_flow.demo.exemplars import sample_camera
    from photoshape_flow.demo.furniture import generate_furniture
    from photoshape_flow.demo.furniture.design import perturb_design
    from photoshape_flow.render import Camera
    from photoshape_flow.render.testing import paper_viewpoints

    views = paper_viewpoints()
    rng = np.random.default_rng(seed)
    pairs = []
    photo_size = int(round(size * 1.6))
    for i in range(n_exact + n_similar):
        similar = i >= n_exact
        furniture = generate_furniture(rng, f"bench-{i}")
        shape = furniture.to_shape_mesh()
        photo_shape = shape
        if similar:
            design = perturb_design(rng, furniture.design)
            photo_shape = generate_furniture(rng, f"bench-{i}-similar", design=design,
                                             segmentation=furniture.segmentation).to_shape_mesh()
        vertices = np.concatenate([p.vertices for p in photo_shape.parts])
        cam = Camera(**sample_camera(rng, vertices))
        beauty = renderer.beauty(photo_shape, None, cam, None, size=photo_size, spp=16, seed=i)
        ids = renderer.part_ids(photo_shape, cam, size=photo_size)
        noisy = np.clip(beauty.srgb.astype(np.float32) + rng.normal(0, 2.0, beauty.srgb.shape), 0, 255)
        mask = beauty.alpha > 0.5
        box = square_box(mask)
        assert box is not None
        rgb = crop_square(noisy.astype(np.uint8), *box, fill=255)
        gt = resize_labels(crop_square(ids, *box, fill=0), size)
        rgb, fg = exemplar_at(rgb, crop_square(mask, *box, fill=False), size)
        az = cam.azimuth + math.radians(rng.normal(0, jitter_deg))
        el = cam.elevation + math.radians(rng.normal(0, jitter_deg))
        pair_camera = nearest_view(views, az, el)
        pairs.append({"shape": shape, "camera": pair_camera, "exemplar_camera": cam, "rgb": rgb, "mask": fg,
                      "gt": None if similar else gt, "kind": furniture.kind})
    return pairs


def evaluate(pairs: list[dict], coarse_maps: list[np.ndarray], params: FineParams, crf: bool = True) -> dict:
    acc = {"coarse": [], "flow": [], "crf": []}
    iou = {"coarse": [], "flow": [], "crf": []}
    seconds = {"flow": [], "crf": []}
    for pair, coarse in zip(pairs, coarse_maps, strict=True):
        t0 = time.perf_counter()
        warped, _ = flow_warp(coarse, pair["mask"], params.flow)
        t1 = time.perf_counter()
        ids = np.unique(coarse)
        cleaned = crf_refine(warped, pair["rgb"], pair["mask"], params.crf, part_ids=ids[ids > 0]) if crf else warped
        t2 = time.perf_counter()
        seconds["flow"].append(t1 - t0)
        seconds["crf"].append(t2 - t1)
        for name, labels in (("coarse", coarse), ("flow", warped), ("crf", cleaned)):
            iou[name].append(silhouette_iou(labels, pair["mask"]))
            if pair["gt"] is not None:
                acc[name].append(part_label_accuracy(labels, pair["gt"]))

    def mean(values: list[float]) -> float | None:
        return round(float(np.mean(values)), 4) if values else None

    return {
        "accuracy": {k: mean(v) for k, v in acc.items()},
        "accuracy_min": {k: (round(float(np.min(v)), 4) if v else None) for k, v in acc.items()},
        "iou": {k: mean(v) for k, v in iou.items()},
        "seconds": {k: mean(v) for k, v in seconds.items()},
        "pairs_with_gt": len(acc["coarse"]),
        "pairs": len(pairs),
    }


def demo_measurement(demo_size: str, work: Path, size: int, methods: list[str]) -> dict:
    """The whole chain on the demo collection; per flow candidate, evaluate_fine_alignment's result."""
    from photoshape_flow.alignment.coarse_alignment import run_coarse_alignment
    from photoshape_flow.alignment.fine_alignment import evaluate_fine_alignment, run_fine_alignment
    from photoshape_flow.config import Settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.demo.generate import generate_demo
    from photoshape_flow.demo.groundtruth import load_groundtruth
    from photoshape_flow.ingest.ingest import ingest_exemplars, ingest_shapes
    from photoshape_flow.render.renderer import Renderer

    settings = Settings(data_root=work / "data")
    migrate.upgrade(settings.resolved_database_url)
    renderer = Renderer()
    timings = {}
    t = time.perf_counter()
    demo_dir = work / "demo"
    generate_demo(demo_dir, demo_size, renderer=renderer)
    timings["generate_demo"] = time.perf_counter() - t
    t = time.perf_counter()
    ingest_shapes(sorted((demo_dir / "shapes").glob("*.obj")), source="demo", settings=settings)
    ingest_exemplars(sorted((demo_dir / "exemplars").glob("*.jpg")), source="demo", settings=settings)
    timings["ingest"] = time.perf_counter() - t
    t = time.perf_counter()
    run_coarse_alignment(settings, renderer=renderer)
    timings["coarse_alignment"] = time.perf_counter() - t
    truth = load_groundtruth(demo_dir)
    out: dict = {"timings": {k: round(v, 1) for k, v in timings.items()}, "methods": {}}
    base = FineParams(size=size)
    for method in methods:
        params = replace(base, flow=replace(base.flow, method=method))
        name = f"flow-crf:{method}"
        summary = run_fine_alignment(settings=settings, method=name, params=params, renderer=renderer)
        with session_scope(settings.resolved_database_url) as session:
            scores = evaluate_fine_alignment(session, truth, method=name, settings=settings)
        out["methods"][method] = {
            **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in scores.items()},
            "pairs": summary["aligned"], "failed": summary["failed"], "seconds_per_pair": summary["seconds_per_pair"],
        }
        print("demo", method, json.dumps(out["methods"][method]))
    return out


def choose_method(result: dict, tolerance: float = 0.005) -> dict:
    """The flow method to use: best mean CRF accuracy over the synthetic and demo measurements;
    methods within `tolerance` of the best count as tied and the fastest flow among them wins."""
    scores: dict[str, float] = {}
    for method, synthetic in result["methods"].items():
        if method == "identity":
            continue
        values = [synthetic["accuracy"]["crf"]]
        demo = result.get("demo", {}).get("methods", {}).get(method)
        if demo is not None:
            values.append(demo["accuracy_crf"])
        scores[method] = round(float(np.mean(values)), 4)
    best = max(scores.values())
    tied = [m for m, v in scores.items() if v >= best - tolerance]
    method = min(tied, key=lambda m: result["methods"][m]["seconds"]["flow"])
    return {"method": method, "scores": scores, "tied": tied, "tolerance": tolerance,
            "rule": "best mean CRF accuracy (synthetic, demo); ties within tolerance go to the fastest flow"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=12, help="pairs with exact ground truth")
    parser.add_argument("--similar", type=int, default=4, help="pairs whose exemplar is a similar shape")
    parser.add_argument("--size", type=int, default=FineParams().size, help="working resolution")
    parser.add_argument("--jitter", type=float, default=3.0, help="retrieval noise, degrees")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", nargs="*", default=list(FLOW_METHODS))
    parser.add_argument("--out", type=Path, default=RESULTS / "fine_alignment.json")
    parser.add_argument("--demo", choices=["tiny", "small", "medium"], help="also measure on the demo collection")
    parser.add_argument("--work", type=Path, help="scratch folder for --demo (default: a temporary one)")
    args = parser.parse_args()

    from photoshape_flow.render.renderer import Renderer

    renderer = Renderer()
    t = time.perf_counter()
    pairs = make_pairs(renderer, args.pairs, args.similar, args.size, args.jitter, args.seed)
    print(f"generated {len(pairs)} pairs in {time.perf_counter() - t:.1f} s")

    base = FineParams(size=args.size)
    render_seconds = []
    coarse_maps = []
    for pair in pairs:
        t0 = time.perf_counter()
        coarse_maps.append(render_coarse_part_map(renderer, pair["shape"], pair["camera"], args.size))
        render_seconds.append(time.perf_counter() - t0)

    methods = {}
    for method in args.methods:
        params = replace(base, flow=replace(base.flow, method=method))
        methods[method] = evaluate(pairs, coarse_maps, params)
        print(method, json.dumps(methods[method]))
    ranked = sorted(
        (m for m in methods if m != "identity"),
        key=lambda m: -(methods[m]["accuracy"]["crf"] or 0.0),
    )

    # the whole step with the default parameters (what the pipeline runs), per pair
    totals = []
    for pair in pairs:
        t0 = time.perf_counter()
        coarse = render_coarse_part_map(renderer, pair["shape"], pair["camera"], args.size)
        align_pair(coarse, pair["rgb"], pair["mask"], base)
        totals.append(time.perf_counter() - t0)

    result = {
        "benchmark": "fine_alignment",
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
        "settings": {
            "size": args.size, "pairs_exact": args.pairs, "pairs_similar": args.similar,
            "jitter_deg": args.jitter, "seed": args.seed, "params": base.to_dict(),
            "crf_backend": "pydensecrf" if pydensecrf_available() else "fallback",
        },
        "methods": methods,
        "ranking_by_crf_accuracy": ranked,
        "default_method": base.flow.method,
        "seconds_per_pair": {
            "render_coarse": round(float(np.mean(render_seconds[1:] or render_seconds)), 4),
            "total_default": round(float(np.mean(totals)), 4),
        },
    }
    if args.demo:
        import tempfile

        with tempfile.TemporaryDirectory(prefix="fine-bench-") as scratch:
            work = args.work or Path(scratch)
            result["demo"] = {"size": args.demo, **demo_measurement(args.demo, work, args.size, args.methods)}
    result["choice"] = choose_method(result)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("choice", "default_method", "seconds_per_pair")}))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()


