"""Three `photoshape run all` started at once on one PostgreSQL collection: each item's result is
written once (every claim won once, every rendering recorded once), every run ends, and the rows
equal an uninterrupted run's where results are deterministic."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from tests.conftest import data_root_with_inbox
from tests.pipeline.whole_runs import PHOTOSHAPE, run_env, snapshot

pytestmark = [pytest.mark.slow, pytest.mark.render, pytest.mark.postgres]


def test_three_concurrent_runs_do_each_item_once(tiny_demo: Path, tmp_path: Path, pg_url: str,
                                                 reference: tuple[Path, dict[str, Any]]) -> None:
    root = data_root_with_inbox(tmp_path / "data", tiny_demo)
    env = run_env(root, pg_url)
    subprocess.run([PHOTOSHAPE, "db", "upgrade"], env=env, check=True, capture_output=True)
    runs = [subprocess.Popen([PHOTOSHAPE, "run", "all", "--profile", "tiny", "--wait"], env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for _ in range(3)]
    outputs = [run.communicate(timeout=1200)[0] for run in runs]
    for run, output in zip(runs, outputs, strict=True):
        assert run.returncode == 0, output[-3000:]
    engine = sa.create_engine(pg_url)
    with engine.connect() as conn:
        twice = conn.execute(sa.text(
            "SELECT stage, item_key, attempts FROM work_claim WHERE attempts > 1 AND item_key <> 'stage'")).all()
        held = conn.execute(sa.text("SELECT COUNT(*) FROM work_claim WHERE state = 'claimed'")).scalar_one()
        renders = dict(conn.execute(sa.text(
            "SELECT kind, COUNT(*) FROM rendering WHERE status = 'ok' GROUP BY kind")).all())
        rewritten = conn.execute(sa.text(  # an upsert of an existing row moves its updated_at
            "SELECT kind, key FROM rendering WHERE updated_at > created_at + INTERVAL '1 second'")).all()
        assignments = conn.execute(sa.text(
            "SELECT COUNT(*) FROM (SELECT pair_id, part_id, method_key, rank FROM assignment "
            "GROUP BY pair_id, part_id, method_key, rank HAVING COUNT(*) > 1) d")).scalar_one()
    engine.dispose()
    assert twice == [], twice  # no item claimed (so computed) a second time; stage-level locks aside
    assert held == 0 and assignments == 0
    assert rewritten == [], rewritten[:10]  # every rendering written once
    assert renders.get("bootstrap") and renders.get("training") and renders.get("photoshape")
    want, got = reference[1], snapshot(pg_url)  # an uninterrupted SQLite run's rows (tests/pipeline/conftest.py)
    for table in ("shape", "part", "exemplar", "material", "envmap", "view_feature", "pair", "alignment",
                  "part_substance", "rendering", "classifier", "assignment"):
        assert got[table] == want[table], f"{table} differs from an uninterrupted run's"
