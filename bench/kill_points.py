"""Kill -9 at every fault-injection point and hit count, each from a fresh data root, then resume.

For each (point, n) of `photoshape_flow.faults.POINTS` x `--hits` the tiny demo's `run all` is killed
at the n-th pass of that point (it must die there), started again with the documented command, and
its rows compared with one uninterrupted run (the comparison of tests/pipeline/test_kill_points.py).
Prints one line per case and a summary; writes bench/results/kill_points.json. SQLite only.

Usage: .venv/bin/python bench/kill_points.py [--hits 1 2 3 4] [--limit N]
About a minute per case on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

TABLES = ("shape", "part", "exemplar", "material", "envmap", "view_feature", "pair", "alignment",
          "part_substance", "rendering", "classifier", "assignment")


def main() -> None:
    from tests.conftest import data_root_with_inbox
    from tests.pipeline.test_kill_points import _die_at
    from tests.pipeline.whole_runs import run_all, snapshot

    from photoshape_flow.demo import generate_demo
    from photoshape_flow.faults import POINTS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hits", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--limit", type=int, default=None, help="stop after this many cases")
    args = parser.parse_args()
    cases = [(point, hit) for hit in args.hits for point in POINTS][: args.limit]
    results = []
    with tempfile.TemporaryDirectory(prefix="photoshape-kill-") as tmp:
        demo = Path(tmp) / "demo"
        generate_demo(demo, "tiny", seed=3)
        reference = data_root_with_inbox(Path(tmp) / "reference", demo)
        assert run_all(reference, None).returncode == 0
        want = snapshot(f"sqlite:///{reference / 'photoshape.db'}")
        for point, hit in cases:
            root = data_root_with_inbox(Path(tmp) / f"{point}-{hit}", demo)
            started = time.perf_counter()
            try:
                _die_at(root, None, point, hit)
            except AssertionError as exc:  # the run never reached that pass of the point
                results.append({"point": point, "hit": hit, "outcome": "not reached", "detail": str(exc)[:200]})
                print(f"{point}:{hit}: not reached")
                shutil.rmtree(root, ignore_errors=True)
                continue
            final = run_all(root, None)
            got = snapshot(f"sqlite:///{root / 'photoshape.db'}")
            differs = [t for t in TABLES if got[t] != want[t]] + (["claims_left"] if got["claims_left"] else [])
            outcome = "identical" if final.returncode == 0 and not differs else "DIFFERENT"
            results.append({"point": point, "hit": hit, "outcome": outcome, "differs": differs,
                            "resume_exit": final.returncode, "seconds": round(time.perf_counter() - started, 1)})
            print(f"{point}:{hit}: {outcome} {differs or ''} ({results[-1]['seconds']} s)", flush=True)
            shutil.rmtree(root, ignore_errors=True)
    killed = [r for r in results if r["outcome"] != "not reached"]
    summary = {"cases": len(results), "killed": len(killed),
               "identical": sum(r["outcome"] == "identical" for r in killed), "date": time.strftime("%Y-%m-%d %H:%M"),
               "results": results}
    print(json.dumps({k: v for k, v in summary.items() if k != "results"}))
    out = REPO / "bench" / "results"
    out.mkdir(exist_ok=True)
    (out / "kill_points.json").write_text(json.dumps(summary, indent=2))
    if summary["identical"] != summary["killed"]:
        raise SystemExit("some resumed runs differ from the uninterrupted one")


if __name__ == "__main__":
    main()
