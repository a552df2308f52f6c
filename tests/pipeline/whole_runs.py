"""A tiny `photoshape run all` as a user starts it (a subprocess, its own environment) and a snapshot of
the rows it leaves, keyed naturally so two runs (or two backends) compare equal when their results are."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import sqlalchemy as sa

PHOTOSHAPE = str(Path(sys.executable).with_name("photoshape"))


def run_env(data_root: Path, url: str | None, **extra: str) -> dict[str, str]:
    """The environment of a run on `data_root` (and `url`, else SQLite under it): no PHOTOSHAPE_ setting of
    the caller's leaks in; seed 3 and one torch thread, so that runs are comparable."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PHOTOSHAPE_")}
    env.update(PHOTOSHAPE_DATA_ROOT=str(data_root), PHOTOSHAPE_SEED="3", PHOTOSHAPE_TORCH_THREADS="1", **extra)
    if url is not None:
        env["PHOTOSHAPE_DATABASE_URL"] = url
    return env


def run_all(data_root: Path, url: str | None, upgrade: bool = True, **extra: str) -> subprocess.CompletedProcess:
    """`photoshape db upgrade` (a new data root's first command; `upgrade=False`: a resumed run, already
    migrated), then `photoshape run all --profile tiny`, as a user would type them."""
    if upgrade:
        subprocess.run([PHOTOSHAPE, "db", "upgrade"], env=run_env(data_root, url), check=True, capture_output=True)
    return subprocess.run([PHOTOSHAPE, "run", "all", "--profile", "tiny"], env=run_env(data_root, url, **extra),
                          capture_output=True, text=True, timeout=1200)


def snapshot(url: str) -> dict[str, Any]:
    """The rows users rely on, keyed naturally (ids may differ between runs)."""
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

    def cell(value: Any) -> Any:  # one spelling per value on both backends
        if type(value).__name__ == "Decimal":
            return float(value)
        if isinstance(value, dict | list):
            return json.dumps(value, sort_keys=True)
        if isinstance(value, str) and value[:1] in "{[":
            return json.dumps(json.loads(value), sort_keys=True)
        return value

    engine = sa.create_engine(url)
    with engine.connect() as conn:
        out: dict[str, Any] = {name: sorted(tuple(cell(v) for v in row) for row in conn.execute(sa.text(sql)))
                               for name, sql in q.items()}
        out["render_blobs"] = {(kind, key): plain(blobs) for kind, key, blobs in
                               conn.execute(sa.text("SELECT kind, key, blobs FROM rendering"))}
        out["metrics"] = {name: plain(metrics) for name, metrics in
                          conn.execute(sa.text("SELECT name, metrics FROM classifier"))}
    engine.dispose()
    return out
