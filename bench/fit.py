"""Fit-stage benchmark: seconds per unit of issue 26 item 7's budgets, on a data root that has run to `fit`.

Run: ``.venv/bin/python bench/fit.py --data-root DIR [--profile medium] [--pairs N] [--calibration]``.
Prints a table and writes ``bench/results/fit.json``.

The budgets (2 cores, medium profile, a cold process included): selection <= 2 s per pair, lighting
<= 3 s per exemplar (amortised), refinement <= 8 s per refined pair, the whole stage <= 70 min on the
medium demo. A generated scene cannot stand for them (the cost depends on the collection's meshes,
materials, envmaps and on which pairs are used), so the bench re-runs the real stage on a copy of a
real data root: DIR's SQLite database is copied to a scratch folder, the copy loses its fit rows,
its stored lightings and its fit claims (and, with ``--calibration``, the stored weight calibration,
which is otherwise reused: it is computed once per classifier and config), and `fitting.fit.run_fit`
runs on the copy's first N pairs (all by default) in a fresh process reading DIR's blobs. The stage's
own per-phase timers (`FitSummary.seconds`) give the split; the process's wall time from its start
(imports, Mitsuba's start, Dr.Jit's kernels from the on-disk cache) gives the cold-process cost.
DIR itself is only read.
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

START = time.perf_counter()
RESULTS = Path(__file__).resolve().parent / "results"


def scratch_copy(data_root: Path, folder: Path, keep_calibration: bool) -> Path:
    """A copy of `data_root`'s database in `folder` without the fit stage's outputs; its path."""
    import sqlalchemy as sa

    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.fitting.context import METHOD
    from photoshape_flow.fitting.fit import LIGHTING_KEY
    from photoshape_flow.networks.calibrations import Calibration

    source = data_root / "photoshape.db"
    if not source.is_file():
        raise SystemExit(f"{source}: no SQLite database here (the bench copies an embedded data root)")
    target = folder / "photoshape.db"
    shutil.copyfile(source, target)
    with session_scope(f"sqlite:///{target}") as session:
        session.execute(sa.delete(m.Assignment).where(m.Assignment.method == METHOD))
        session.execute(sa.delete(m.WorkClaim).where(m.WorkClaim.stage.like(f"{METHOD}:%")))
        for exemplar in session.execute(sa.select(m.Exemplar)).scalars():
            if LIGHTING_KEY in (exemplar.meta or {}):
                exemplar.meta = {k: v for k, v in exemplar.meta.items() if k != LIGHTING_KEY}
        if not keep_calibration:
            for classifier in session.execute(sa.select(m.Classifier)).scalars():
                Calibration.store(classifier, fit=None)  # none stored: the run fits the weights again
    return target


def probe(profile: str, pairs: int, overrides: list[str]) -> dict:
    """Runs the stage (this process is fresh) and returns its summary and timings."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.fitting.fit import run_fit
    from photoshape_flow.fitting.pairs import fit_pairs_of
    from photoshape_flow.method_keys import MethodKey
    from photoshape_flow.networks.classifier_rows import resolve_classifier
    from photoshape_flow.profiles import resolve_profile

    cfg = resolve_profile(profile, overrides).profile.fit
    settings = get_settings()
    with session_scope(settings.resolved_database_url) as session:
        classifier = resolve_classifier(session)
        if classifier is None:
            raise SystemExit("no trained classifier in this data root: run the pipeline to `inference` first")
        todo = fit_pairs_of(session, str(MethodKey.for_classifier(classifier.id)))
    todo = todo[:pairs] if pairs > 0 else todo
    imported = time.perf_counter() - START
    summary = run_fit(cfg, pair_ids=todo, settings=settings)
    return {"pairs": len(todo), "done": summary.pairs_done, "failed": len(summary.pairs_failed),
            "lightings": summary.lightings, "refined_pairs": summary.refined_pairs,
            "refined_parts": summary.refined, "seconds": summary.seconds, "per_unit": summary.per_unit(),
            "weights": summary.weights.get("source"), "imports_s": imported,
            "process_s": time.perf_counter() - START}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--data-root", type=Path, required=True, help="a data root that has run to `fit` (read only)")
    parser.add_argument("--profile", default="medium")
    parser.add_argument("--pairs", type=int, default=0, help="the first N pairs (0: all)")
    parser.add_argument("--calibration", action="store_true", help="drop the stored calibration and time it too")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="profile override")
    parser.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.probe:
        print(json.dumps(probe(args.profile, args.pairs, args.set)))
        return
    data_root = args.data_root.resolve()
    with tempfile.TemporaryDirectory(prefix="bench-fit-") as folder:
        database = scratch_copy(data_root, Path(folder), keep_calibration=not args.calibration)
        env = {**os.environ, "PHOTOSHAPE_DATA_ROOT": folder, "PHOTOSHAPE_DATABASE_URL": f"sqlite:///{database}",
               "PHOTOSHAPE_BLOB_ROOT": str(data_root / "blobs")}
        load_before = os.getloadavg()
        proc = subprocess.run([sys.executable, __file__, "--probe", "--data-root", str(data_root), "--profile",
                               args.profile, "--pairs", str(args.pairs), *(f"--set={s}" for s in args.set)],
                              env=env, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"the stage's process failed:\n{proc.stderr[-3000:]}")
        run = json.loads(proc.stdout.strip().splitlines()[-1])
    record = {"data_root": str(data_root), "profile": args.profile, "overrides": args.set,
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "machine": platform.platform(),
              "cpus": os.cpu_count(), "load_average_before": load_before, "load_average_after": os.getloadavg(),
              "run": run}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "fit.json").write_text(json.dumps(record, indent=1))
    seconds, unit = run["seconds"], run["per_unit"]
    print("| pairs (failed) | lightings | refined pairs | process s | imports s | calibration s | reading s "
          "| selection s per pair | lighting s per exemplar | refinement s per refined pair |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print(f"| {run['done']} ({run['failed']}) | {run['lightings']} | {run['refined_pairs']} | {run['process_s']:.0f} "
          f"| {run['imports_s']:.1f} | {seconds.get('calibration', 0.0):.0f} | {seconds.get('reading', 0.0):.0f} "
          f"| {unit['selection_per_pair']} | {unit['lighting_per_exemplar']} | {unit['refinement_per_refined_pair']} |")
    print(f"load average before {load_before}, after {os.getloadavg()}")


if __name__ == "__main__":
    main()
