"""Fan-out of the render-heavy stages over 1 and 2 local Dask worker processes: same rows, and the speed-up.

Builds the tiny demo collection up to fine alignment once (in-process), copies that data root for each
worker count, and runs one stage's Prefect flow (`substances` or `training-renders`) in a subprocess
with `PHOTOSHAPE_DASK_WORKERS=N` (an ephemeral Prefect server; the stage's units are claimed in the
work table by the worker processes). Reports the flow's wall time per worker count and checks that
every run wrote the same rendering rows (keys and params hashes). Writes bench/results/fanout.json.

Usage: .venv/bin/python bench/fanout.py [--stage training-renders] [--count 64] [--workers 1 2]
       [--set training_renders.size=128 --set training_renders.spp=32]
Measure on an otherwise idle machine (2 cores: one heavy job at a time).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

FLOW = """
import json, sys, time
from photoshape_flow.flows.stages import STAGE_FLOWS
start = time.perf_counter()
result = STAGE_FLOWS[sys.argv[1]](profile="tiny", overrides=sys.argv[2:], batch_size=8)
print(json.dumps({"seconds": time.perf_counter() - start, "result": result}))
"""


def build(root: Path) -> None:
    """The tiny demo, ingested, aligned (and with part substances for training renders)."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db.session import get_engine
    from photoshape_flow.demo import generate_demo
    from photoshape_flow.ingest.ingest_stage import IngestRequest
    from photoshape_flow.stages import run_all

    demo = root.parent / "demo-input"
    generate_demo(demo, "tiny", seed=3)
    os.environ["PHOTOSHAPE_DATA_ROOT"] = str(root)
    get_settings.cache_clear()
    get_engine.cache_clear()
    migrate.upgrade()
    from photoshape_flow.flows.events import stage_context

    roots = {name: [str(demo / name)] for name in ("envmaps", "materials", "shapes", "exemplars")}
    run_all("tiny", stage_context(), names=["ingest", "coarse-alignment", "fine-alignment", "substances"],
            ingest=IngestRequest(roots=roots), origin="bench")
    get_engine.cache_clear()


def rows(root: Path, kind: str) -> dict[str, str]:
    import sqlalchemy as sa

    engine = sa.create_engine(f"sqlite:///{root / 'photoshape.db'}")
    with engine.connect() as conn:
        out = dict(conn.execute(sa.text("SELECT key, params_hash FROM rendering WHERE kind = :k AND status = 'ok'"),
                                {"k": kind}).all())
    engine.dispose()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", choices=("training-renders", "substances"), default="training-renders")
    parser.add_argument("--count", type=int, default=64, help="renders to make")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        help="more profile overrides, e.g. training_renders.size=128")
    args = parser.parse_args()
    field, kind = (("training_renders.count", "training") if args.stage == "training-renders"
                   else ("substances.bootstrap_count", "bootstrap"))
    with tempfile.TemporaryDirectory(prefix="photoshape-fanout-") as tmp:
        base = Path(tmp) / "base"
        started = time.perf_counter()
        build(base)
        print(f"collection built in {time.perf_counter() - started:.0f} s")
        baseline = rows(base, kind)
        results = []
        for workers in args.workers:
            root = Path(tmp) / f"workers-{workers}"
            shutil.copytree(base, root, symlinks=True)
            env = {**os.environ, "PHOTOSHAPE_DATA_ROOT": str(root), "PHOTOSHAPE_DASK_WORKERS": str(workers),
                   "PREFECT_API_URL": "", "DO_NOT_TRACK": "1", "OMP_NUM_THREADS": "1"}
            env.pop("PHOTOSHAPE_DATABASE_URL", None)
            out = subprocess.run([sys.executable, "-c", FLOW, args.stage, f"{field}={args.count}", *args.overrides],
                                 env=env,
                                 capture_output=True, text=True, cwd=REPO)
            if out.returncode != 0:
                raise SystemExit(f"{workers} workers: flow failed\n{out.stderr[-3000:]}")
            report = json.loads(out.stdout.strip().splitlines()[-1])
            made = rows(root, kind)
            results.append({"workers": workers, "seconds": round(report["seconds"], 1),
                            "done": report["result"]["done"], "rows": len(made),
                            "rows_hash": hash(tuple(sorted(made.items()))), "new_rows": len(set(made) - set(baseline))})
            print(f"{workers} worker(s): {report['seconds']:.1f} s, {report['result']['done']} rendered, "
                  f"{len(made)} rows")
        same = len({r["rows_hash"] for r in results}) == 1
        first = results[0]["seconds"]
        for r in results:
            r["speedup"] = round(first / r["seconds"], 2)
            del r["rows_hash"]
        record = {"stage": args.stage, "count": args.count, "overrides": args.overrides, "same_rows": same,
                  "results": results,
                  "machine": f"{platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                  "date": time.strftime("%Y-%m-%d %H:%M"), "load": os.getloadavg()[0]}
        print(json.dumps(record, indent=2))
        out_dir = REPO / "bench" / "results"
        out_dir.mkdir(exist_ok=True)
        (out_dir / "fanout.json").write_text(json.dumps(record, indent=2))
        if not same:
            raise SystemExit("the worker counts wrote different rows")


if __name__ == "__main__":
    main()
