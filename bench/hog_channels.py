"""Which HOG channels should coarse alignment keep? Measured on the demo's ground truth.

The original PhotoShape code kept only the last 8 of the 31 Felzenszwalb channels (1,352-D); this
bench compares channel sets (and a stronger blur) on a demo collection:

- every collection shape is swept over the paper's 456 views once (shaded, `render_size` pixels);
  the 31-channel HOG of every view is kept and each channel set is a slice of it;
- every demo exemplar (its photo, with the ground-truth part mask > 0 as the foreground mask, or a
  white-threshold mask like a product-photo ingest would compute) is a query;
- shape recall@1/@5 for exemplars whose shape is in the collection, the same for held-out shapes
  against the collection shape they were derived from (``similar_to``), and the median azimuth /
  elevation error at the true shape's retrieved view.

It also measures the ``bf16`` search mode's recall@k against the exact search on these real
descriptors (queries: the exemplars plus every view of held-out-in-the-bench shapes searched
against the other shapes).

    .venv/bin/python bench/hog_channels.py --size medium [--demo DIR] [--render-size 200]

Writes bench/results/hog_channels.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from photoshape_flow.align.descriptors import HogParams, prepare, to_grey
from photoshape_flow.align.hog import CHANNEL_SETS, channel_indices, hog
from photoshape_flow.align.index import ArrayDatabase
from photoshape_flow.align.retrieval import recall_at_k, search
from photoshape_flow.align.viewpoints import PAPER_456, angular_errors_deg, viewpoint_array, viewpoints

RESULTS = Path(__file__).resolve().parent / "results"


def load_demo(demo: Path, size: str, seed: int):  # type: ignore[no-untyped-def]
    from photoshape_flow.demo.groundtruth import load_groundtruth

    if not (demo / "groundtruth.json").is_file():
        from photoshape_flow.demo.generate import generate_demo

        print(f"generating the {size} demo in {demo} ...", file=sys.stderr)
        generate_demo(demo, size, seed)
    return load_groundtruth(demo)


def shape_meshes(gt) -> dict[str, object]:  # type: ignore[no-untyped-def]
    from photoshape_flow.geometry.prepare import prepare_shape
    from photoshape_flow.geometry.preprocess import PreprocessOptions

    out = {}
    for sid, truth in sorted(gt.shapes.items()):
        if truth.in_collection:
            out[sid] = prepare_shape(str(truth.path), "obj", str(gt.root), PreprocessOptions()).mesh
    return out


def sweep_hog(meshes: dict, variants: dict[str, HogParams], render_size: int) -> tuple[dict, float, float]:
    """Per variant: (S, 456, rows, cols, 31) float16 HOG of every view; plus render and HOG seconds."""
    from photoshape_flow.render.renderer import Renderer

    renderer = Renderer()
    cams = viewpoints(PAPER_456)
    out: dict[str, list[np.ndarray]] = {name: [] for name in variants}
    t_render = t_hog = 0.0
    for i, (sid, mesh) in enumerate(meshes.items()):
        t = time.perf_counter()
        sweep = renderer.sweep(mesh, cams, size=render_size, shaded=True)
        t_render += time.perf_counter() - t
        t = time.perf_counter()
        for name, params in variants.items():
            pairs = zip(sweep.shaded, sweep.part_ids, strict=True)
            prepared = np.stack([prepare(g, ids > 0, params) for g, ids in pairs])
            out[name].append(hog(prepared, params.cell).astype(np.float16))
        t_hog += time.perf_counter() - t
        print(f"  swept {sid} ({i + 1}/{len(meshes)})", file=sys.stderr)
    return {k: np.stack(v) for k, v in out.items()}, t_render, t_hog


def threshold_mask(rgb: np.ndarray) -> np.ndarray:
    """Foreground = not near-white (a product-photo ingest's simple threshold), largest blobs kept."""
    import cv2

    grey = to_grey(rgb)
    fg = (grey < 0.94).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return fg > 0


def exemplar_hog(gt, variants: dict[str, HogParams], mask_kind: str) -> tuple[list[str], dict[str, np.ndarray]]:  # type: ignore[no-untyped-def]
    import cv2

    stems = sorted(gt.exemplars)
    out: dict[str, list[np.ndarray]] = {name: [] for name in variants}
    for stem in stems:
        e = gt.exemplars[stem]
        rgb = cv2.imread(str(e.image), cv2.IMREAD_COLOR)[..., ::-1]
        mask = e.load_mask() > 0 if mask_kind == "gt" else threshold_mask(rgb)
        for name, params in variants.items():
            out[name].append(hog(prepare(to_grey(rgb), mask, params), params.cell))
    return stems, {k: np.stack(v) for k, v in out.items()}


def evaluate(gt, stems, shape_ids, found, cams) -> dict[str, float]:  # type: ignore[no-untyped-def]
    hits1 = hits5 = n_in = sim1 = sim5 = n_held = 0
    az, el = [], []
    d_right, d_other = [], []  # top-1 distances: true shape (or its parent) vs anything else
    for i, stem in enumerate(stems):
        e = gt.exemplars[stem]
        listed = [shape_ids[s] for s in found.shapes[i] if s >= 0]
        if listed:
            good = listed[0] == (e.shape if e.in_collection else e.similar_to)
            (d_right if good else d_other).append(float(found.distances[i, 0]))
        if e.in_collection:
            n_in += 1
            hits1 += listed[:1] == [e.shape]
            hits5 += e.shape in listed[:5]
            if e.shape in listed:
                v = int(found.views[i, listed.index(e.shape)])
                daz, dele = angular_errors_deg(cams[v, 0], cams[v, 1], e.camera.azimuth, e.camera.elevation)
                az.append(float(daz))
                el.append(float(dele))
        elif e.similar_to:
            n_held += 1
            sim1 += listed[:1] == [e.similar_to]
            sim5 += e.similar_to in listed[:5]
    return {
        "recall@1": hits1 / max(n_in, 1), "recall@5": hits5 / max(n_in, 1), "n_in_collection": n_in,
        "similar@1": sim1 / max(n_held, 1), "similar@5": sim5 / max(n_held, 1), "n_heldout": n_held,
        "median_azimuth_error_deg": float(np.median(az)) if az else float("nan"),
        "median_elevation_error_deg": float(np.median(el)) if el else float("nan"),
        "azimuth_within_15deg": float(np.mean(np.asarray(az) <= 15)) if az else float("nan"),
        "top1_distance_right_p50_p90_max": [float(np.percentile(d_right, p)) for p in (50, 90, 100)] if d_right else [],
        "top1_distance_wrong_p10_p50": [float(np.percentile(d_other, p)) for p in (10, 50)] if d_other else [],
    }


def bf16_recall(db: np.ndarray, queries: np.ndarray, k: int, rng: np.random.Generator, max_view_queries: int) -> dict:
    """Recall of the bf16 mode against exact: exemplar queries on the full database, plus the views of
    a held-out tenth of the shapes against the other nine tenths."""
    out = {}
    exact = search(queries, ArrayDatabase(db), k)
    fast = search(queries, ArrayDatabase(db), k, mode="bf16")
    out["exemplars"] = {"queries": len(queries), "recall": recall_at_k(exact, fast)}
    order = rng.permutation(db.shape[0])
    held, kept = np.sort(order[: max(1, db.shape[0] // 10)]), np.sort(order[max(1, db.shape[0] // 10) :])
    views = db[held].reshape(-1, db.shape[2]).astype(np.float32)
    pick = rng.choice(len(views), size=min(max_view_queries, len(views)), replace=False)
    base = ArrayDatabase(db[kept])
    t = time.perf_counter()
    exact = search(views[pick], base, k)
    t_exact = time.perf_counter() - t
    t = time.perf_counter()
    fast = search(views[pick], base, k, mode="bf16")
    t_fast = time.perf_counter() - t
    out["heldout_views"] = {
        "queries": len(pick), "recall": recall_at_k(exact, fast), "seconds_exact": t_exact, "seconds_bf16": t_fast,
        "top1_agreement": float(np.mean(exact.shapes[:, 0] == fast.shapes[:, 0])),
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="small", choices=["tiny", "small", "medium"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--demo", type=Path, default=None, help="demo folder (default: /tmp/photoshape-bench-demo/<size>)")
    ap.add_argument("--render-size", type=int, default=200)
    ap.add_argument("--k", type=int, default=8, help="shapes per exemplar (bf16 recall@k)")
    ap.add_argument("--view-queries", type=int, default=4000)
    ap.add_argument("--out", type=Path, default=RESULTS / "hog_channels.json")
    args = ap.parse_args()
    import torch

    demo = args.demo or Path("/tmp/photoshape-bench-demo") / args.size
    gt = load_demo(demo, args.size, args.seed)
    meshes = shape_meshes(gt)
    shape_ids = list(meshes)
    variants = {"sigma0.1": HogParams(blur_sigma=0.1), "sigma1.0": HogParams(blur_sigma=1.0)}
    print(f"{len(meshes)} shapes, {len(gt.exemplars)} exemplars; sweeping 456 views each ...", file=sys.stderr)
    db_hog, t_render, t_hog = sweep_hog(meshes, variants, args.render_size)
    cams = viewpoint_array(PAPER_456)
    rows = []
    for mask_kind in ("gt", "threshold"):
        stems, ex_hog = exemplar_hog(gt, variants, mask_kind)
        for variant in variants:
            for channels in CHANNEL_SETS:
                if mask_kind == "threshold" and variant != "sigma0.1":
                    continue
                keep = list(channel_indices(channels))
                db = db_hog[variant][..., keep].reshape(len(shape_ids), 456, -1)
                q = ex_hog[variant][..., keep].reshape(len(stems), -1).astype(np.float32)
                found = search(q, ArrayDatabase(db), 5)
                row = {"channels": channels, "blur": variant, "mask": mask_kind, "dims": int(db.shape[2])}
                row.update(evaluate(gt, stems, shape_ids, found, cams))
                rows.append(row)
    best = max(
        (r for r in rows if r["mask"] == "gt" and r["blur"] == "sigma0.1"),
        key=lambda r: (r["recall@1"] + r["similar@1"], r["recall@5"], -r["median_azimuth_error_deg"]),
    )
    rng = np.random.default_rng(0)
    recall = {}
    for channels in ("energy8", best["channels"]):
        keep = list(channel_indices(channels))
        db = db_hog["sigma0.1"][..., keep].reshape(len(shape_ids), 456, -1)
        stems, ex_hog = exemplar_hog(gt, {"sigma0.1": variants["sigma0.1"]}, "gt")
        q = ex_hog["sigma0.1"][..., keep].reshape(len(stems), -1).astype(np.float32)
        recall[channels] = bf16_recall(db, q, args.k, rng, args.view_queries)
    result = {
        "demo": {"size": args.size, "seed": args.seed, "root": str(demo), "shapes": len(shape_ids),
                 "exemplars": len(gt.exemplars)},
        "render_size": args.render_size, "views": 456,
        "seconds_per_shape": {
            "sweep": t_render / len(shape_ids), "prepare+hog31 (2 blur variants)": t_hog / len(shape_ids)
        },
        "rows": rows, "best_gt_mask": best, "bf16_recall": recall,
        "machine": {"platform": platform.platform(), "torch_threads": torch.get_num_threads()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    print(f"{'channels':26s} {'blur':9s} {'mask':9s} {'dims':>5s} {'R@1':>5s} {'R@5':>5s} {'sim@1':>5s} "
          f"{'az°':>5s} {'el°':>5s}")
    for r in rows:
        print(f"{r['channels']:26s} {r['blur']:9s} {r['mask']:9s} {r['dims']:5d} {r['recall@1']:5.2f} "
              f"{r['recall@5']:5.2f} {r['similar@1']:5.2f} {r['median_azimuth_error_deg']:5.1f} "
              f"{r['median_elevation_error_deg']:5.1f}")
    summary = ", ".join(
        f"{c}: {v['exemplars']['recall']:.4f} / {v['heldout_views']['recall']:.4f}" for c, v in recall.items()
    )
    print(f"best (gt mask, sigma 0.1): {best['channels']}; bf16 recall@{args.k} (exemplars / views): {summary}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
