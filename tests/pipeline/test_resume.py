"""A pipeline run killed with SIGKILL at several points and started again ends exactly like an
uninterrupted run: no duplicate rows, no missing rows, the same results.

Tolerances: rows are compared on their natural keys and values; blob refs (content hashes of maps,
renders and features) must be equal, except rendered images, whose pixels may differ by at most 1/255
on average (the renderer is seeded from each item's key), and classifier metrics (1e-6).
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tests.conftest import data_root_with_inbox

from photoshape_flow.store import BlobStore

pytestmark = [pytest.mark.slow, pytest.mark.render]

PHOTOSHAPE = str(Path(sys.executable).with_name("photoshape"))

# (description, SQL that returns a positive number once the run is past that point)
KILL_POINTS: list[tuple[str, str]] = [
    ("during fine alignment", "SELECT COUNT(*) FROM alignment"),
    ("during the bootstrap renders", "SELECT COUNT(*) >= 4 FROM rendering WHERE kind = 'bootstrap'"),
    ("during classifier training", "SELECT COUNT(*) FROM classifier WHERE kind = 'material'"),
    # a killed holder's claims are taken over at once by the resumed run (its pid is gone), not after the lease
    ("during inference, claims held",
     "SELECT COUNT(*) FROM work_claim WHERE stage LIKE 'inference:%' AND state = 'claimed'"),
    ("during publish, claims held",
     "SELECT COUNT(*) FROM work_claim WHERE stage LIKE 'publish:%' AND state = 'claimed'"),
]


def _env(data_root: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PHOTOSHAPE_")}
    env.update(PHOTOSHAPE_DATA_ROOT=str(data_root), PHOTOSHAPE_SEED="3", PHOTOSHAPE_TORCH_THREADS="1")
    return env


def _run_all(data_root: Path) -> subprocess.CompletedProcess:
    subprocess.run([PHOTOSHAPE, "db", "upgrade"], env=_env(data_root), check=True, capture_output=True)
    return subprocess.run([PHOTOSHAPE, "run", "all", "--profile", "tiny"], env=_env(data_root),
                          capture_output=True, text=True, timeout=1200)


def _query(db: Path, sql: str) -> int:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1) as conn:
            return int(conn.execute(sql).fetchone()[0] or 0)
    except sqlite3.Error:
        return 0


def _run_and_kill(data_root: Path, condition: str, timeout: float = 900) -> bool:
    """Start `run all`, SIGKILL it once `condition` holds; False when the run finished first."""
    subprocess.run([PHOTOSHAPE, "db", "upgrade"], env=_env(data_root), check=True, capture_output=True)
    proc = subprocess.Popen([PHOTOSHAPE, "run", "all", "--profile", "tiny"], env=_env(data_root),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    db = data_root / "photoshape.db"
    deadline = time.time() + timeout
    while proc.poll() is None and time.time() < deadline:
        if _query(db, condition) > 0:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            return True
        time.sleep(0.1)
    proc.wait()
    return False


def snapshot(data_root: Path) -> dict[str, Any]:
    """The rows users rely on, keyed naturally (ids may differ between runs)."""
    db = data_root / "photoshape.db"
    q = {
        "shape": "SELECT source, source_id, status, mesh_blob, num_faces FROM shape",
        "part": "SELECT s.source_id, p.\"index\", p.name, ROUND(p.uv_density, 6) FROM part p "
                "JOIN shape s ON s.id = p.shape_id",
        "exemplar": "SELECT source_id, status, image_blob, mask_blob, duplicate_of_id IS NULL FROM exemplar",
        "material": "SELECT name, substance, status, maps FROM material",
        "envmap": "SELECT name, split, blob FROM envmap",
        "view_feature": "SELECT s.source_id, v.descriptor, v.feature_blob FROM view_feature v "
                        "JOIN shape s ON s.id = v.shape_id",
        "pair": "SELECT s.source_id, e.source_id, p.rank, p.view_index, ROUND(p.distance, 4) FROM pair p "
                "JOIN shape s ON s.id = p.shape_id JOIN exemplar e ON e.id = p.exemplar_id",
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
    with sqlite3.connect(db) as conn:
        out: dict[str, Any] = {name: sorted(map(tuple, conn.execute(sql).fetchall())) for name, sql in q.items()}
        out["render_blobs"] = {
            (kind, key): blobs for kind, key, blobs in conn.execute("SELECT kind, key, blobs FROM rendering")
        }
        out["metrics"] = dict(conn.execute("SELECT name, metrics FROM classifier").fetchall())
    return out


def _assert_same_images(a: Path, b: Path, refs_a: dict, refs_b: dict) -> None:
    import json

    store_a, store_b = BlobStore(a / "blobs"), BlobStore(b / "blobs")
    for key, blobs in refs_a.items():
        other = json.loads(refs_b[key])
        for name, ref in json.loads(blobs).items():
            if ref == other.get(name):
                continue
            img_a = store_a.load_image(ref).astype(np.float64)
            img_b = store_b.load_image(other[name]).astype(np.float64)
            scale = 255.0 if img_a.max() > 1.5 else 1.0
            assert np.abs(img_a - img_b).mean() / scale <= 1 / 255, (key, name)


def test_killed_run_resumes_to_the_same_rows(tiny_demo: Path, tmp_path: Path) -> None:
    reference = data_root_with_inbox(tmp_path / "reference", tiny_demo)
    done = _run_all(reference)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    resumed = data_root_with_inbox(tmp_path / "resumed", tiny_demo)
    kills = [desc for desc, condition in KILL_POINTS if _run_and_kill(resumed, condition)]
    assert len(kills) >= 2, f"the run finished before most kill points: killed {kills}"
    final = _run_all(resumed)
    assert final.returncode == 0, final.stdout[-3000:] + final.stderr[-3000:]

    want, got = snapshot(reference), snapshot(resumed)
    assert got["claims_left"] == [] and want["claims_left"] == []
    for table in ("shape", "part", "exemplar", "material", "envmap", "view_feature", "pair", "alignment",
                  "part_substance", "rendering", "classifier", "assignment"):
        assert got[table] == want[table], f"{table} differs after resuming ({kills})"
    _assert_same_images(reference, resumed, want["render_blobs"], got["render_blobs"])
    import json

    for name, metrics in want["metrics"].items():
        a, b = json.loads(metrics), json.loads(got["metrics"][name])
        for key, value in a.items():
            if isinstance(value, float) and "second" not in key and "per_s" not in key:
                assert b[key] == pytest.approx(value, abs=1e-6), (name, key)
