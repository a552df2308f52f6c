"""`pipeline/groundtruth_registry.py`: which file `eval` and the evaluate deployment use by default."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pytest
import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import GroundTruthFile
from photoshape_flow.scoring.groundtruth_registry import register_groundtruth, resolve_groundtruth


def gt_file(path: Path, sha: str) -> GroundTruthFile:
    path.write_text("{}")
    return GroundTruthFile(path=path, sha256=sha, version=2, entries=(), problems=())


def test_the_last_used_existing_file_wins_then_the_newest_demo(db_url: str, settings_env: Path,
                                                               tmp_path: Path) -> None:
    assert resolve_groundtruth("given.json") == (Path("given.json"), False)  # a given file is never replaced
    with pytest.raises(ValueError, match="no ground truth given, none registered and no demo"):
        resolve_groundtruth(None)
    demo = settings_env / "demo" / "tiny" / "groundtruth.json"
    demo.parent.mkdir(parents=True)
    demo.write_text("{}")
    assert resolve_groundtruth(None) == (demo, True)
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    with session_scope(db_url) as session:
        register_groundtruth(session, gt_file(first, "1" * 64), 3, 1)
    with session_scope(db_url) as session:
        register_groundtruth(session, gt_file(second, "2" * 64), 5, 0)
    assert resolve_groundtruth(None) == (second, True)
    with session_scope(db_url) as session:  # the first file used again, edited: same row, new hash
        register_groundtruth(session, gt_file(first, "3" * 64), 4, 0)
        session.flush()
        rows = session.execute(sa.select(m.GroundTruthFileRow).order_by(m.GroundTruthFileRow.id)).scalars().all()
        assert [(r.path, r.sha256, r.entries) for r in rows] == [(str(first), "3" * 64, 4), (str(second), "2" * 64, 5)]
        rows[0].used_at = dt.datetime.now(dt.UTC) + dt.timedelta(seconds=1)  # clocks may tie within a test
    assert resolve_groundtruth(None) == (first, True)
    first.unlink()  # a registered file that is gone is passed over
    assert resolve_groundtruth(None) == (second, True)
