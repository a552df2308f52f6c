"""The kill-9 harness: a tiny `photoshape run all` killed with SIGKILL at named fault-injection
points (`photoshape_flow.faults`), each run resumed by the documented command (`photoshape run all`)
and the result compared with one uninterrupted run per backend: no duplicate rows, no missing rows,
no claims left, the same results.

Each killed run dies at its point (exit -9 and the point's name in the mark file) and the next run
resumes from what it left, so one data root passes every point in pipeline order. Tolerances: rows
are compared on their natural keys and values; blob refs (content hashes of maps, renders and
features) must be equal, except rendered images, whose pixels may differ by at most 1/255 on average
(the renderer is seeded from each item's key), and classifier metrics (1e-6). Torch runs on one
thread. bench/kill_points.py runs every point count separately.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tests.conftest import data_root_with_inbox

from photoshape_flow.store import BlobStore

pytestmark = [pytest.mark.slow, pytest.mark.render]

PHOTOSHAPE = str(Path(sys.executable).with_name("photoshape"))

# (point, hit count) in pipeline order: SQLite passes all of them, PostgreSQL the first of each kind
SQLITE_POINTS = [
    ("ingest-blob-before-row", 2),
    ("claimed-before-result", 1),
    ("rendering-blobs-before-row", 3),
    ("substance-checkpoint-saved", 1),
    ("training-checkpoint-saved", 1),
    ("inference-pair-done", 2),
    ("export-writing", 2),
    ("gallery-writing", 1),
]
POSTGRES_POINTS = [("ingest-blob-before-row", 1), ("rendering-blobs-before-row", 2),
                   ("training-checkpoint-saved", 1), ("export-writing", 1)]


def _env(data_root: Path, url: str | None, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PHOTOSHAPE_")}
    env.update(PHOTOSHAPE_DATA_ROOT=str(data_root), PHOTOSHAPE_SEED="3", PHOTOSHAPE_TORCH_THREADS="1", **extra)
    if url is not None:
        env["PHOTOSHAPE_DATABASE_URL"] = url
    return env


def _run_all(data_root: Path, url: str | None, **extra: str) -> subprocess.CompletedProcess:
    subprocess.run([PHOTOSHAPE, "db", "upgrade"], env=_env(data_root, url), check=True, capture_output=True)
    return subprocess.run([PHOTOSHAPE, "run", "all", "--profile", "tiny"], env=_env(data_root, url, **extra),
                          capture_output=True, text=True, timeout=1200)


def _die_at(data_root: Path, url: str | None, point: str, hit: int) -> None:
    """A run that must die at `point` (its `hit`-th pass): exit -9 and the point named in the mark file."""
    mark = data_root.parent / f"{data_root.name}-mark.txt"
    mark.unlink(missing_ok=True)
    out = _run_all(data_root, url, PHOTOSHAPE_FAULT=f"{point}:{hit}", PHOTOSHAPE_FAULT_MARK=str(mark))
    died = mark.read_text().split() if mark.exists() else []
    assert out.returncode == -signal.SIGKILL and died == [point], (point, out.returncode, died,
                                                                 out.stdout[-1500:] + out.stderr[-1500:])


def snapshot(url: str) -> dict[str, Any]:
    """The rows users rely on, keyed naturally (ids may differ between runs)."""
    import json

    import sqlalchemy as sa

    q = {
        "shape": "SELECT source, source_id, status, mesh_blob, num_faces FROM shape",
        "part": "SELECT s.source_id, p.\"index\", p.name, ROUND(CAST(p.uv_density AS NUMERIC), 6) FROM part p "
                "JOIN shape s ON s.id = p.shape_id",
        "exemplar": "SELECT source_id, status, image_blob, mask_blob, duplicate_of_id IS NULL FROM exemplar",
        "material": "SELECT name, substance, status, maps FROM material",
        "envmap": "SELECT name, split, blob FROM envmap",
        "view_feature": "SELECT s.source_id, v.descriptor, v.feature_blob FROM view_feature v "
                        "JOIN shape s ON s.id = v.shape_id",
        "pair": "SELECT s.source_id, e.source_id, p.rank, p.view_index, ROUND(CAST(p.distance AS NUMERIC), 4) "
                "FROM pair p JOIN shape s ON s.id = p.shape_id JOIN exemplar e ON e.id = p.exemplar_id",
        "alignment": "SELECT s.source_id, e.source_id, a.status, a.crf_blob FROM alignment a "
                     "JOIN pair p ON p.id = a.pair_id JOIN shape s ON s.id = p.shape_id "
                     "JOIN exemplar e ON e.id = p.exemplar_id",
        "part_substance": "SELECT s.source_id, e.source_id, pt.\"index\", ps.observed, ps.substance "
                          "FROM part_substance ps JOIN pair p ON p.id = ps.pair_id JOIN shape s ON s.id = p.shape_id "
                          "JOIN exemplar e ON e.id = p.exemplar_id JOIN part pt ON pt.id = ps.part_id",
        "rendering": "SELECT kind, key, status FROM rendering",
        "classifier": "SELECT name, kind, status, epoch FROM classifier",
        "assignment": "SELECT s.source_id, e.source_id, pt.\"index\", a.method, a.rank, m.name FROM assignment a "
                      "JOIN pair p ON p.id = a.pair_id JOIN shape s ON s.id = p.shape_id "
                      "JOIN exemplar e ON e.id = p.exemplar_id JOIN part pt ON pt.id = a.part_id "
                      "LEFT JOIN material m ON m.id = a.material_id",
        "claims_left": "SELECT stage, item_key FROM work_claim WHERE state = 'claimed'",
    }
    def plain(value: Any) -> Any:  # JSON columns: text on SQLite, parsed on PostgreSQL
        return json.loads(value) if isinstance(value, str) else value

    engine = sa.create_engine(url)
    with engine.connect() as conn:
        out: dict[str, Any] = {name: sorted(tuple(float(v) if type(v).__name__ == "Decimal" else v for v in row)
                                            for row in conn.execute(sa.text(sql))) for name, sql in q.items()}
        out["render_blobs"] = {(kind, key): plain(blobs) for kind, key, blobs in
                               conn.execute(sa.text("SELECT kind, key, blobs FROM rendering"))}
        out["metrics"] = {name: plain(metrics) for name, metrics in
                          conn.execute(sa.text("SELECT name, metrics FROM classifier"))}
    engine.dispose()
    return out


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

    import sqlalchemy as sa

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
                                                          request: pytest.FixtureRequest) -> None:
    points = SQLITE_POINTS if backend == "sqlite" else POSTGRES_POINTS
    reference = data_root_with_inbox(tmp_path / "reference", tiny_demo)
    ref_url = _url(backend, reference, request, "ref")
    done = _run_all(reference, ref_url)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    resumed = data_root_with_inbox(tmp_path / "resumed", tiny_demo)
    url = _url(backend, resumed, request, "resumed")
    for point, hit in points:
        _die_at(resumed, url, point, hit)
    final = _run_all(resumed, url)  # the documented command: run it again
    assert final.returncode == 0, final.stdout[-3000:] + final.stderr[-3000:]

    def where(root: Path, db_url: str | None) -> str:
        return db_url or f"sqlite:///{root / 'photoshape.db'}"

    want, got = snapshot(where(reference, ref_url)), snapshot(where(resumed, url))
    assert got["claims_left"] == [] and want["claims_left"] == []
    for table in ("shape", "part", "exemplar", "material", "envmap", "view_feature", "pair", "alignment",
                  "part_substance", "rendering", "classifier", "assignment"):
        assert got[table] == want[table], f"{table} differs after resuming ({points})"
    _assert_same_images(reference, resumed, want["render_blobs"], got["render_blobs"])
    for name, metrics in want["metrics"].items():
        for key, value in (metrics or {}).items():
            if isinstance(value, float) and "second" not in key and "per_s" not in key:
                assert got["metrics"][name][key] == pytest.approx(value, abs=1e-6), (name, key)
