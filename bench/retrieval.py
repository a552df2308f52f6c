"""Coarse-alignment retrieval cost: exact (and bf16) top-k search at growing scale, up to paper scale.

Paper scale is 40,927 exemplars x 5,740 shapes x 456 views x 1,352 dims (2.6 M views, 7.1 GB as
float16, ~2.9e14 FLOP). The database is generated shard by shard on the fly (a small pool of random
float16 chunks is recycled, so generating it costs nothing and memory stays bounded); a subsample
of queries is searched against the *whole* database and the time is extrapolated linearly to all
exemplars. Each scale runs in a child process so its peak RSS (getrusage) is its own. Next to every
search the machine's own matmul rate is measured in the same child on the same GEMM shape
(torch.mm of a query batch by a chunk), so "fraction of matmul" says how much the search loses to
its bookkeeping (norms, float16 -> float32, per-shape minimum, top-k merge).

Also measured: the shaded 456-view sweep + descriptor time per shape (Mitsuba, a procedural chair),
and, when bench/hog_channels.py has run, the bf16 mode's recall on real demo descriptors.

    .venv/bin/python bench/retrieval.py                      # reduced scale (default)
    .venv/bin/python bench/retrieval.py --shapes 100,1000,5740 --query-sample 2048

Writes bench/results/retrieval.json and prints a table.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
PAPER = {"exemplars": 40927, "shapes": 5740, "views": 456, "dims": 1352}


class SyntheticDatabase:
    """`num_shapes` random float16 shards served from a recycled pool of pre-generated chunks."""

    def __init__(self, num_shapes: int, num_views: int, dims: int, chunk_shapes: int, pool: int = 3, seed: int = 0):
        self.num_shapes, self.num_views, self.dims = num_shapes, num_views, dims
        rng = np.random.default_rng(seed)
        n = min(chunk_shapes, num_shapes)
        # HOG-like magnitudes: non-negative, mostly small
        self.pool = [(rng.random((n, num_views, dims), np.float32) * 0.25).astype(np.float16) for _ in range(pool)]
        self.chunk_shapes = n

    def load(self, start: int, stop: int) -> np.ndarray:
        buf = self.pool[(start // self.chunk_shapes) % len(self.pool)]
        return buf[: stop - start]


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def matmul_rate(batch: int, rows: int, dims: int, reps: int, dtype: str = "float32") -> float:
    """GFLOP/s of torch.mm(query batch, chunk.T): the search's GEMM shape, alone."""
    import torch

    dt = getattr(torch, dtype)
    a = torch.rand(batch, dims).to(dt)
    b = torch.rand(rows, dims).to(dt)
    torch.mm(a, b.T)
    t = time.perf_counter()
    for _ in range(reps):
        torch.mm(a, b.T)
    seconds = (time.perf_counter() - t) / reps
    return 2.0 * batch * rows * dims / seconds / 1e9


def one(args: argparse.Namespace) -> dict:
    """Child process: one (scale, mode) search; prints a JSON line."""
    import torch

    from photoshape_flow.align.retrieval import search

    shapes, views, dims, nq = args.one, args.views, args.dims, args.query_sample
    step = max(1, args.chunk_rows // max(1, views))  # whole shapes per chunk, as the search streams them
    base_rss = peak_rss_gb()
    db = SyntheticDatabase(shapes, views, dims, step)
    rng = np.random.default_rng(1)
    queries = (rng.random((nq, dims), np.float32) * 0.25).astype(np.float32)
    qb = min(args.query_batch, nq)
    stats: dict[str, float] = {}
    t = time.perf_counter()
    found = search(queries, db, args.k, mode=args.mode, chunk_rows=args.chunk_rows, query_batch=args.query_batch,
                   stats=stats)
    seconds = time.perf_counter() - t
    # with all exemplars, each chunk's one-off preparation is shared by 40,927 queries instead of
    # `nq`: scale only the per-query part
    per_chunk = stats["prepare_s"] + stats["load_wait_s"]
    full_seconds = per_chunk + (seconds - per_chunk) * PAPER["exemplars"] / nq
    assert found.shapes.shape == (nq, args.k)
    flop = 2.0 * nq * shapes * views * dims
    mm32 = matmul_rate(qb, step * views, dims, args.mm_reps)
    mm = matmul_rate(qb, step * views, dims, args.mm_reps, "bfloat16") if args.mode == "bf16" else mm32
    return {
        "mode": args.mode, "shapes": shapes, "views": views, "dims": dims, "db_views": shapes * views,
        "db_gb_fp16": shapes * views * dims * 2 / 1e9, "queries_timed": nq, "k": args.k,
        "chunk_rows": step * views, "query_batch": qb, "seconds": seconds,
        "us_per_query_view": seconds / (nq * shapes * views) * 1e6,
        "gflops": flop / seconds / 1e9, "matmul_gflops": mm, "fraction_of_matmul": flop / seconds / 1e9 / mm,
        "speedup_vs_fp32_matmul": (flop / seconds / 1e9) / mm32,
        "search_stats": stats,
        "extrapolated_seconds_all_exemplars": full_seconds,
        "extrapolated_fraction_of_matmul": 2.0 * PAPER["exemplars"] * shapes * views * dims / full_seconds / 1e9 / mm,
        "peak_rss_gb": peak_rss_gb(), "rss_before_gb": base_rss, "torch_threads": torch.get_num_threads(),
    }


def sweep_cost(render_size: int) -> dict:
    """Seconds per shape for the 456-view shaded sweep and its descriptors (procedural chair)."""
    from photoshape_flow.align.descriptors import HogParams, view_descriptors
    from photoshape_flow.align.viewpoints import viewpoints
    from photoshape_flow.render.renderer import Renderer
    from photoshape_flow.render.testing import procedural_chair

    params = HogParams(render_size=render_size)
    cams = viewpoints()
    out = {"render_size": render_size, "views": len(cams)}
    renderer = Renderer()
    for faces in (2000, 20000):
        mesh = procedural_chair(faces)
        renderer.sweep(mesh, cams[:4], size=render_size)  # scene load + kernels
        t = time.perf_counter()
        sweep = renderer.sweep(mesh, cams, size=render_size, shaded=True)
        t_sweep = time.perf_counter() - t
        t = time.perf_counter()
        view_descriptors(sweep.shaded, sweep.part_ids, params)
        t_desc = time.perf_counter() - t
        out[f"faces_{mesh.num_faces}"] = {"sweep_s": t_sweep, "descriptors_s": t_desc, "total_s": t_sweep + t_desc}
    return out


def run_child(argv: list[str]) -> dict:
    proc = subprocess.run([sys.executable, __file__, *argv], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"child {argv} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", default="100,400,1600,5740", help="database sizes in shapes (456 views each)")
    ap.add_argument("--query-sample", type=int, default=512, help="queries timed per scale (extrapolated)")
    ap.add_argument("--views", type=int, default=PAPER["views"])
    ap.add_argument("--dims", type=int, default=PAPER["dims"])
    ap.add_argument("--k", type=int, default=8)
    ap.add_argument("--chunk-rows", type=int, default=16384)
    ap.add_argument("--query-batch", type=int, default=2048)
    ap.add_argument("--modes", default="exact,bf16")
    ap.add_argument("--mm-reps", type=int, default=5)
    ap.add_argument("--no-sweep", action="store_true")
    ap.add_argument("--render-size", type=int, default=200)
    ap.add_argument("--out", type=Path, default=RESULTS / "retrieval.json")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--mode", default="exact", help=argparse.SUPPRESS)
    ap.add_argument("--sweep-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one is not None:
        print(json.dumps(one(args)))
        return
    if args.sweep_only:
        print(json.dumps(sweep_cost(args.render_size)))
        return

    common = ["--views", str(args.views), "--dims", str(args.dims), "--k", str(args.k),
              "--chunk-rows", str(args.chunk_rows), "--query-batch", str(args.query_batch),
              "--mm-reps", str(args.mm_reps)]
    rows = []
    for mode in args.modes.split(","):
        for shapes in (int(s) for s in args.shapes.split(",")):
            row = run_child(["--one", str(shapes), "--mode", mode, "--query-sample", str(args.query_sample), *common])
            rows.append(row)
            print(f"  {mode:5s} {shapes:5d} shapes: {row['seconds']:.1f} s, {row['gflops']:.0f} GFLOP/s "
                  f"({row['fraction_of_matmul']:.0%} of matmul), peak {row['peak_rss_gb']:.2f} GB", file=sys.stderr)
    # memory with every paper-scale query held at once (the database streams, so one chunk suffices)
    full_q = run_child(["--one", str(max(1, args.chunk_rows // args.views)), "--mode", "exact",
                        "--query-sample", str(PAPER["exemplars"]), *common])
    sweep = None
    if not args.no_sweep:
        try:
            sweep = run_child(["--sweep-only", "--render-size", str(args.render_size)])
        except RuntimeError as exc:
            sweep = {"error": str(exc)[-300:]}
    channels = RESULTS / "hog_channels.json"
    real_recall = json.loads(channels.read_text()).get("bf16_recall") if channels.is_file() else None
    paper_flop = 2.0 * PAPER["exemplars"] * PAPER["shapes"] * PAPER["views"] * PAPER["dims"]
    paper_gb = PAPER["shapes"] * PAPER["views"] * PAPER["dims"] * 2e-9
    result = {
        "paper_scale": {**PAPER, "flop": paper_flop, "db_gb_fp16": paper_gb},
        "rows": rows,
        "all_queries_memory": full_q,
        "sweep_per_shape": sweep,
        "bf16_recall_real_descriptors": real_recall,
        "machine": {"platform": platform.platform(), "python": platform.python_version()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))

    print(f"{'mode':5s} {'shapes':>6s} {'views':>9s} {'GB fp16':>7s} {'Q timed':>7s} {'s':>7s} {'us/q/view':>9s} "
          f"{'GFLOP/s':>7s} {'mm GF/s':>7s} {'of mm':>6s} {'all-Q s':>8s} {'of mm':>6s} {'peak GB':>7s}")
    for r in rows:
        print(f"{r['mode']:5s} {r['shapes']:6d} {r['db_views']:9d} {r['db_gb_fp16']:7.2f} {r['queries_timed']:7d} "
              f"{r['seconds']:7.1f} {r['us_per_query_view']:9.4f} {r['gflops']:7.0f} {r['matmul_gflops']:7.0f} "
              f"{r['fraction_of_matmul']:6.0%} {r['extrapolated_seconds_all_exemplars']:8.0f} "
              f"{r['extrapolated_fraction_of_matmul']:6.0%} {r['peak_rss_gb']:7.2f}")
    print("(first 'of mm': as timed; 'all-Q s' and the second 'of mm': extrapolated to all exemplars)")
    print(f"all {PAPER['exemplars']} queries held at once: peak {full_q['peak_rss_gb']:.2f} GB")
    if sweep:
        print(f"sweep + descriptors per shape: {json.dumps(sweep)}")
    if real_recall:
        print(f"bf16 recall on real demo descriptors: {json.dumps(real_recall)}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
