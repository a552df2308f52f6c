"""The `evaluate` flow's exemplar batches over 1 and 2 local Dask worker processes: same figures, and the speed-up.

Runs the flow in a subprocess per worker count (`PHOTOSHAPE_DASK_WORKERS=N`, an ephemeral Prefect
server) on a copy of an existing data root's database (the evaluation writes its rows; the blobs are
shared read-only), then checks every run stored the same figures and intervals: exactly, except the
rendered ones (re-render and relighting errors), which may differ by `RENDERED_TOLERANCE`: Mitsuba's
LLVM renders are not bit-reproducible from run to run under load (the same seed gave 3 different
images of one pair in 4 concurrent processes, one pixel off by 1/255; docs/benchmarks.md). Writes
bench/results/eval_fanout.json.

Usage: .venv/bin/python bench/eval_fanout.py DATA_ROOT GROUNDTRUTH [--source S] [--batch-size 14] [--workers 1 2]
Measure on an otherwise idle machine (2 cores: one heavy job at a time).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RENDERED = ("rerender_", "relight_")  # metric prefixes computed from Mitsuba renders
RENDERED_TOLERANCE = 1e-3  # absolute, on errors of 0.05-0.3 (one pixel off by 1/255 moves them ~1e-5)

FLOW = """
import json, sys, time
from photoshape_flow.flows.evaluate import evaluate
start = time.perf_counter()
result = evaluate(groundtruth=sys.argv[1], run="bench", source=sys.argv[2] or None, batch_size=int(sys.argv[3]),
                  stages=["inference"])
print(json.dumps({"seconds": time.perf_counter() - start, "metrics": len(result["table"])}))
"""


def figures(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as conn:
        return sorted(conn.execute("SELECT stage, method, metric, value, count, ci_low, ci_high FROM evaluation "
                                   "WHERE run = 'bench'").fetchall())


def differences(a: list[tuple], b: list[tuple]) -> tuple[list[str], float]:
    """Figures that differ beyond what each kind allows, and the largest rendered difference."""
    keyed_a, keyed_b = ({row[:3]: row[3:] for row in rows} for rows in (a, b))
    problems = [f"{key}: only in one run" for key in sorted(set(keyed_a) ^ set(keyed_b))]
    largest = 0.0
    for key in sorted(set(keyed_a) & set(keyed_b)):
        (va, na, la, ha), (vb, nb, lb, hb) = keyed_a[key], keyed_b[key]
        if na != nb:
            problems.append(f"{key}: counts {na} vs {nb}")
            continue
        rendered = key[2].startswith(RENDERED)
        for x, y in ((va, vb), (la, lb), (ha, hb)):
            if x is None or y is None:
                if x is not y:
                    problems.append(f"{key}: {x} vs {y}")
                continue
            gap = abs(x - y)
            if rendered:
                largest = max(largest, gap)
            if gap > (RENDERED_TOLERANCE if rendered else 0.0):
                problems.append(f"{key}: {x} vs {y}")
    return problems, largest


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data_root", type=Path)
    parser.add_argument("groundtruth", type=Path)
    parser.add_argument("--source", default="")
    parser.add_argument("--batch-size", type=int, default=14)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.workers:
            db = Path(tmp) / f"w{n}.db"
            with sqlite3.connect(args.data_root / "photoshape.db") as src, sqlite3.connect(db) as dst:
                src.backup(dst)
            env = {**os.environ, "PHOTOSHAPE_DATA_ROOT": str(args.data_root), "PHOTOSHAPE_DASK_WORKERS": str(n),
                   "PHOTOSHAPE_DATABASE_URL": f"sqlite:///{db}", "PREFECT_API_URL": "",
                   "PREFECT_HOME": str(Path(tmp) / f"prefect{n}")}
            out = subprocess.run([sys.executable, "-c", FLOW, str(args.groundtruth), args.source,
                                  str(args.batch_size)], env=env, capture_output=True, text=True, check=True)
            runs[n] = {**json.loads(out.stdout.strip().splitlines()[-1]), "figures": figures(db)}
            print(f"{n} worker(s): {runs[n]['seconds']:.1f} s, {runs[n]['metrics']} figures", flush=True)
    first = runs[args.workers[0]]
    problems, largest, identical = [], 0.0, True
    for r in runs.values():
        found, gap = differences(first["figures"], r["figures"])
        problems += found
        largest = max(largest, gap)
        identical = identical and r["figures"] == first["figures"]
    for line in problems:
        print("differs:", line)
    same = not problems
    result = {"machine": platform.platform(), "cpus": os.cpu_count(), "load": os.getloadavg(),
              "batch_size": args.batch_size, "same_figures": same, "bit_identical": identical,
              "largest_rendered_difference": largest,
              "seconds": {n: round(r["seconds"], 1) for n, r in runs.items()},
              "speedup": {n: round(first["seconds"] / r["seconds"], 2) for n, r in runs.items()}}
    (REPO / "bench" / "results").mkdir(exist_ok=True)
    (REPO / "bench" / "results" / "eval_fanout.json").write_text(json.dumps(result, indent=1))
    print(json.dumps(result, indent=1))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
