"""Run records stay true: a run whose process was killed is marked `died`, never counted as running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import sqlalchemy as sa
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope


def _killed_run(data_root: Path) -> int:
    """A child process starts a recorded run and is SIGKILLed in it; returns the run's id."""
    script = textwrap.dedent("""
        import os, signal
        from photoshape_flow.profiles import resolve_profile
        from photoshape_flow.pipeline.context import StageContext
        from photoshape_flow.stages.run import start_run
        run_id = start_run(StageContext.create(), resolve_profile("tiny"), ["ingest"], "cli")
        print(run_id, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    env = {**os.environ, "PHOTOSHAPE_DATA_ROOT": str(data_root)}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == -signal.SIGKILL, done.stderr
    return int(done.stdout.split()[0])


def test_status_shows_a_killed_run_as_died(db_url: str, settings_env: Path) -> None:
    run_id = _killed_run(settings_env)
    with session_scope(db_url) as session:
        assert session.get(m.PipelineRun, run_id).status == "running"  # as the killed process left it
    result = CliRunner().invoke(app, ["status"])
    flat = " ".join(result.output.split())
    assert result.exit_code == 0 and "died: 1" in flat and "running" not in flat, result.output
    with session_scope(db_url) as session:
        row = session.get(m.PipelineRun, run_id)
        assert row.status == "died" and row.finished_at is not None and f":{row.holder_pid})" in row.error


def test_a_live_run_stays_running_and_a_new_run_sweeps_dead_ones(db_url: str, settings_env: Path) -> None:
    from photoshape_flow.pipeline.context import StageContext
    from photoshape_flow.pipeline.runs import mark_dead_runs
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.stages.run import finish_run, start_run

    dead = _killed_run(settings_env)
    ctx = StageContext.create()
    live = start_run(ctx, resolve_profile("tiny"), ["ingest"], "cli")  # this process: alive
    with session_scope(db_url) as session:
        statuses = dict(session.execute(sa.select(m.PipelineRun.id, m.PipelineRun.status)).all())
        assert statuses == {dead: "died", live: "running"}
        assert mark_dead_runs(session) == []
    finish_run(ctx, live, None)
    with session_scope(db_url) as session:
        assert session.get(m.PipelineRun, live).status == "ok"
