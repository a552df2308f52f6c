"""Interrupted runs leave nothing transient behind: `photoshape run all` stopped with Ctrl-C (SIGINT) or
killed (SIGKILL) at fault-injection points (`photoshape_flow.faults`), then the real `photoshape status`
and a resumed run. No claim stays `claimed`, no classifier stays `training`, and the later successful
run's status reports nothing pending or failed for training."""

from __future__ import annotations

import re
import signal
import subprocess
from pathlib import Path

import pytest
import sqlalchemy as sa
from tests.conftest import data_root_with_inbox
from tests.pipeline.whole_runs import PHOTOSHAPE, run_all, run_env

pytestmark = [pytest.mark.slow, pytest.mark.render]


def _rows(root: Path, query: str) -> list[tuple]:
    engine = sa.create_engine(f"sqlite:///{root / 'photoshape.db'}")
    with engine.connect() as conn:
        rows = [tuple(r) for r in conn.execute(sa.text(query))]
    engine.dispose()
    return rows


def _status_row(root: Path, stage: str) -> list[str]:
    out = subprocess.run([PHOTOSHAPE, "status"], env=run_env(root, None), capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    line = next(line for line in out.stdout.splitlines() if re.match(rf"[│┃] {re.escape(stage)} ", line))
    return [cell.strip() for cell in re.split(r"[│┃]", line) if cell.strip()]


def _stopped_at(root: Path, point: str, how: str) -> subprocess.CompletedProcess:
    mark = root.parent / "mark.txt"
    mark.unlink(missing_ok=True)
    out = run_all(root, None, PHOTOSHAPE_FAULT=f"{point}:1", PHOTOSHAPE_FAULT_SIGNAL=how,
                  PHOTOSHAPE_FAULT_MARK=str(mark))
    assert mark.read_text().split() == [point], out.stdout[-2000:] + out.stderr[-2000:]
    return out


def test_interrupted_and_killed_runs_leave_no_transient_rows(tiny_demo: Path, tmp_path: Path) -> None:
    root = data_root_with_inbox(tmp_path / "root", tiny_demo)
    # Ctrl-C right after a batch's items were claimed: they go back, the run is recorded as failed
    out = _stopped_at(root, "claimed-before-result", "INT")
    assert out.returncode == 130  # what Ctrl-C makes a typer command exit with
    assert _rows(root, "SELECT stage, item_key FROM work_claim WHERE state = 'claimed'") == []
    assert _rows(root, "SELECT status FROM pipeline_run") == [("failed",)]
    # killed outright after a network's first checkpoint: its classifier row said `training` for good
    out = _stopped_at(root, "training-checkpoint-saved", "KILL")
    assert out.returncode == -signal.SIGKILL
    assert _rows(root, "SELECT status FROM classifier WHERE status = 'training'") == [("training",)]
    # the real `status`: the dead run died, nobody trains that row any more: failed, not pending
    stage, unit, done, pending, failed, rejected = _status_row(root, "training")
    assert (pending, failed) == ("0", "1")
    assert _rows(root, "SELECT status FROM classifier WHERE status = 'training'") == []
    assert [s for (s,) in _rows(root, "SELECT status FROM pipeline_run ORDER BY id")] == ["failed", "died"]
    # the documented command resumes it (from its checkpoint); then nothing is pending, failed or claimed
    final = run_all(root, None)
    assert final.returncode == 0, final.stdout[-3000:] + final.stderr[-3000:]
    stage, unit, done, pending, failed, rejected = _status_row(root, "training")
    assert (pending, failed) == ("0", "0") and int(done) >= 1
    assert _rows(root, "SELECT status FROM classifier WHERE status <> 'ok'") == []
    assert _rows(root, "SELECT stage, item_key FROM work_claim WHERE state = 'claimed'") == []
