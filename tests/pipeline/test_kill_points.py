"""The kill-9 harness: a tiny `photoshape run all` killed with SIGKILL at named fault-injection
points (`photoshape_flow.faults`), each run resumed by the documented command (`photoshape run all`)
and the result compared with one uninterrupted run on SQLite (shared by both backends: the rows a
resumed PostgreSQL run leaves must equal an embedded one's too): no duplicate rows, no missing rows,
no claims left, the same results.

Each killed run dies at its point (exit -9 and the point's name in the mark file) and the next run
resumes from what it left, so one data root passes every point in pipeline order. On SQLite one point
is Ctrl-C (SIGINT) instead, and the real `photoshape status` is read after the training kill and at the
end: an interrupted run leaves nothing transient (no claim `claimed`, no classifier `training`) that a
later successful run would still report. Tolerances: rows
are compared on their natural keys and values; blob refs (content hashes of maps, renders and
features) must be equal, except rendered images, whose pixels may differ by at most 1/255 on average
(the renderer is seeded from each item's key), and classifier metrics (1e-6). Torch runs on one
thread. bench/kill_points.py runs every point count separately.
"""

from __future__ import annotations

import re
import signal
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import sqlalchemy as sa
from tests.conftest import data_root_with_inbox
from tests.pipeline.whole_runs import PHOTOSHAPE, run_all, run_env, snapshot

from photoshape_flow.store import BlobStore

pytestmark = [pytest.mark.slow, pytest.mark.render]

# (point, hit count) in pipeline order: SQLite passes all of them; PostgreSQL the two whose recovery
# is the database's (a blob stored before its row under a claim, a classifier row left `training`):
# ingest's point is the rendering's pattern again, and the export's files do not depend on the backend
SQLITE_POINTS = [
    ("ingest-blob-before-row", 2),
    ("claimed-before-result", 1),  # Ctrl-C on SQLite (INTERRUPTED)
    ("rendering-blobs-before-row", 3),
    ("substance-checkpoint-saved", 1),
    ("training-checkpoint-saved", 1),
    ("inference-pair-done", 2),
    ("export-writing", 2),
    ("gallery-writing", 1),
]
POSTGRES_POINTS = [("rendering-blobs-before-row", 2), ("training-checkpoint-saved", 1)]
INTERRUPTED = "claimed-before-result"  # SQLite's Ctrl-C point: right after a batch's items were claimed


def _die_at(data_root: Path, url: str | None, point: str, hit: int, how: str = "KILL", first: bool = False) -> None:
    """A run that must stop at `point` (its `hit`-th pass) and name it in the mark file: exit -9 when
    killed, 130 (what Ctrl-C makes a typer command exit with) when interrupted. `first`: the data
    root's first run, which migrates its database."""
    mark = data_root.parent / f"{data_root.name}-mark.txt"
    mark.unlink(missing_ok=True)
    out = run_all(data_root, url, upgrade=first, PHOTOSHAPE_FAULT=f"{point}:{hit}", PHOTOSHAPE_FAULT_MARK=str(mark),
                  PHOTOSHAPE_FAULT_SIGNAL=how)
    died = mark.read_text().split() if mark.exists() else []
    code = -signal.SIGKILL if how == "KILL" else 130
    assert out.returncode == code and died == [point], (point, out.returncode, died,
                                                       out.stdout[-1500:] + out.stderr[-1500:])


def _rows(url: str, query: str) -> list[tuple]:
    engine = sa.create_engine(url)
    with engine.connect() as conn:
        rows = [tuple(r) for r in conn.execute(sa.text(query))]
    engine.dispose()
    return rows


def _training_status(root: Path) -> tuple[int, int, int]:
    """(done, pending, failed) of the training row of the real `photoshape status`."""
    out = subprocess.run([PHOTOSHAPE, "status"], env=run_env(root, None), capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    line = next(line for line in out.stdout.splitlines() if re.match(r"[│┃] training ", line))
    stage, unit, done, pending, failed, rejected = [c.strip() for c in re.split(r"[│┃]", line) if c.strip()]
    return int(done), int(pending), int(failed)


def _after(point: str, root: Path, url: str) -> None:
    """What an interrupted run must leave (SQLite): nothing transient that later runs would report."""
    if point == INTERRUPTED:  # Ctrl-C: its claims go back, the run is recorded as failed
        assert _rows(url, "SELECT stage, item_key FROM work_claim WHERE state = 'claimed'") == []
        assert _rows(url, "SELECT status FROM pipeline_run ORDER BY id DESC LIMIT 1") == [("failed",)]
    if point == "training-checkpoint-saved":  # killed outright: its classifier row said `training` for good
        assert _rows(url, "SELECT status FROM classifier WHERE status = 'training'") == [("training",)]
        _, pending, failed = _training_status(root)  # nobody trains that row any more: failed, not pending
        assert (pending, failed) == (0, 1)
        assert _rows(url, "SELECT status FROM classifier WHERE status = 'training'") == []
        assert _rows(url, "SELECT status FROM pipeline_run ORDER BY id DESC LIMIT 1") == [("died",)]


def _assert_same_images(a: Path, b: Path, refs_a: dict, refs_b: dict) -> None:
    store_a, store_b = BlobStore(a / "blobs"), BlobStore(b / "blobs")
    for key, blobs in refs_a.items():
        other = refs_b[key] or {}
        for name, ref in (blobs or {}).items():
            if ref == other.get(name):
                continue
            img_a = store_a.load_image(ref).astype(np.float64)
            img_b = store_b.load_image(other[name]).astype(np.float64)
            scale = 255.0 if img_a.max() > 1.5 else 1.0
            assert np.abs(img_a - img_b).mean() / scale <= 1 / 255, (key, name)


def _url(backend: str, root: Path, request: pytest.FixtureRequest, name: str) -> str | None:
    """None (SQLite under the data root) or a fresh PostgreSQL database, dropped after the test."""
    if backend == "sqlite":
        return None
    import uuid

    admin_url = request.getfixturevalue("pg_admin_url")
    db = f"photoshape_kill_{name}_{uuid.uuid4().hex[:8]}"
    admin = sa.create_engine(admin_url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(sa.text(f'CREATE DATABASE "{db}"'))

    def drop() -> None:
        with admin.connect() as conn:
            conn.execute(sa.text(f'DROP DATABASE IF EXISTS "{db}" WITH (FORCE)'))
        admin.dispose()

    request.addfinalizer(drop)
    return admin_url.rsplit("/", 1)[0] + f"/{db}"


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)])
def test_runs_killed_at_each_point_resume_to_the_same_rows(backend: str, tiny_demo: Path, tmp_path: Path,
                                                          reference: tuple[Path, dict[str, Any]],
                                                          request: pytest.FixtureRequest) -> None:
    points = SQLITE_POINTS if backend == "sqlite" else POSTGRES_POINTS
    resumed = data_root_with_inbox(tmp_path / "resumed", tiny_demo)
    url = _url(backend, resumed, request, "resumed")
    sqlite = f"sqlite:///{resumed / 'photoshape.db'}"
    for n, (point, hit) in enumerate(points):
        _die_at(resumed, url, point, hit, "INT" if backend == "sqlite" and point == INTERRUPTED else "KILL", n == 0)
        if backend == "sqlite":
            _after(point, resumed, sqlite)
    final = run_all(resumed, url, upgrade=False)  # the documented command: run it again
    assert final.returncode == 0, final.stdout[-3000:] + final.stderr[-3000:]
    if backend == "sqlite":  # the later successful run reports nothing pending or failed for training
        done, pending, failed = _training_status(resumed)
        assert (pending, failed) == (0, 0) and done >= 1

    (reference_root, want), got = reference, snapshot(url or sqlite)
    assert got["claims_left"] == [] and want["claims_left"] == []
    for table in ("shape", "part", "exemplar", "material", "envmap", "view_feature", "pair", "alignment",
                  "part_substance", "rendering", "classifier", "assignment"):
        assert got[table] == want[table], f"{table} differs after resuming ({backend}: {points})"
    _assert_same_images(reference_root, resumed, want["render_blobs"], got["render_blobs"])
    for name, metrics in want["metrics"].items():
        for key, value in (metrics or {}).items():
            if isinstance(value, float) and "second" not in key and "per_s" not in key:
                assert got["metrics"][name][key] == pytest.approx(value, abs=1e-6), (name, key)
