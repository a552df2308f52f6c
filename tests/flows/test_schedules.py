"""Schedules fire: against a real Prefect server on 127.0.0.1, a deployment served the way `photoshape serve`
serves it gets flow runs from the server's scheduler (`auto_scheduled`, never created by this test), and
the served process runs one of them to completion.

This is the behaviour that broke with SQLAlchemy 2.1 (Prefect 3.8.8's scheduler raised "Can't evaluate
bulk DML statement" every loop, so no scheduled run was ever made); tests/flows/test_deployments.py only
checks that the deployment objects carry their schedules.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from photoshape_flow.flows.deployments import load_declarations
from tests.flows.conftest import running_prefect_server

pytestmark = [pytest.mark.prefect, pytest.mark.slow]

INTERVAL_S = 10  # the test deployment's schedule
SCHEDULED_WAIT_S = 90  # bound on the wait for the first scheduled run (the scheduler looks every 2-5 s)
COMPLETED_WAIT_S = 180  # bound on the wait for a completed run

# The server's scheduler settings for this test: look often, and keep a short horizon so an interval
# of seconds makes a handful of runs, not max_runs of them.
SCHEDULER = {
    "PREFECT_SERVER_SERVICES_SCHEDULER_LOOP_SECONDS": "5",
    "PREFECT_SERVER_SERVICES_SCHEDULER_RECENT_DEPLOYMENTS_LOOP_SECONDS": "2",
    "PREFECT_SERVER_SERVICES_SCHEDULER_MIN_RUNS": "3",
    "PREFECT_SERVER_SERVICES_SCHEDULER_MIN_SCHEDULED_TIME": "PT60S",
    "PREFECT_SERVER_SERVICES_SCHEDULER_MAX_RUNS": "10",
}

SERVE = ("import sys; from pathlib import Path; from photoshape_flow.flows.deployments import serve; "
         "serve(None, limit=1, path=Path(sys.argv[1]))")


def _runs(api_url: str) -> dict[str, list[Any]]:
    """The flow runs of each served deployment, by deployment name, through the Prefect client."""
    from prefect.client.orchestration import get_client
    from prefect.settings import PREFECT_API_URL, temporary_settings

    async def main() -> dict[str, list[Any]]:
        async with get_client() as client:
            names = {d.id: d.name for d in await client.read_deployments()}
            out: dict[str, list[Any]] = {name: [] for name in names.values()}
            for run in await client.read_flow_runs():
                out[names[run.deployment_id]].append(run)
            return out

    with temporary_settings({PREFECT_API_URL: api_url}):
        return asyncio.run(main())


def _state(run: Any) -> str:
    return run.state_type.value if run.state_type else ""


def _wait_for(what: str, seconds: float, until, api_url: str, serve: subprocess.Popen,  # type: ignore[no-untyped-def]
              serve_log: Path, server_log: Path) -> dict[str, list[Any]]:
    """Poll the deployment's runs until `until(runs)`; fail early on a failed run or a dead serving process."""
    deadline = time.time() + seconds
    while time.time() < deadline:
        runs = _runs(api_url)
        if until(runs):
            return runs
        failed = [r for rs in runs.values() for r in rs if _state(r) in ("FAILED", "CRASHED")]
        assert not failed, f"{failed[0].state}\n{serve_log.read_text()[-3000:]}"
        assert serve.poll() is None, f"serving process exited:\n{serve_log.read_text()[-3000:]}"
        time.sleep(1)
    seen = [(name, _state(r), r.auto_scheduled) for name, rs in runs.items() for r in rs]
    pytest.fail(f"no {what} within {seconds} s; runs: {seen}\n"
                f"server log:\n{server_log.read_text()[-3000:]}\nserve log:\n{serve_log.read_text()[-2000:]}")


def test_the_servers_scheduler_makes_runs_and_one_completes(tmp_path: Path) -> None:
    # an empty, migrated data root: publish has nothing to do and completes in seconds
    env = {k: v for k, v in os.environ.items() if k != "PHOTOSHAPE_DATABASE_URL"}
    env.update(PHOTOSHAPE_DATA_ROOT=str(tmp_path / "data"), PHOTOSHAPE_TORCH_THREADS="1", DO_NOT_TRACK="1")
    photoshape = str(Path(sys.executable).with_name("photoshape"))
    subprocess.run([photoshape, "db", "upgrade"], env=env, check=True, capture_output=True, timeout=120)

    # prefect.yaml's own nightly deployment as declared (cron at 02:00 UTC), and its publish deployment with
    # a tiny profile and a schedule every INTERVAL_S seconds
    declared = {d["name"]: d for d in load_declarations()}
    publish = {**declared["publish"], "parameters": {"profile": "tiny"}, "schedules": [{"interval": INTERVAL_S}]}
    declarations = tmp_path / "prefect.yaml"
    declarations.write_text(yaml.safe_dump({"deployments": [declared["nightly"], publish]}))

    home = tmp_path / "prefect-home"
    home.mkdir()
    with running_prefect_server(home, **SCHEDULER) as server:
        serve_log = tmp_path / "serve.log"
        with open(serve_log, "w") as log:
            serve = subprocess.Popen(
                [sys.executable, "-c", SERVE, str(declarations)],
                env={**env, **server, "PREFECT_RUNNER_POLL_FREQUENCY": "2"},
                stdout=log, stderr=subprocess.STDOUT)
        watch = (server["PREFECT_API_URL"], serve, serve_log, home / "server.log")
        try:
            def scheduled(runs: dict[str, list[Any]]) -> bool:
                return all(any(r.auto_scheduled and _state(r) == "SCHEDULED" for r in runs.get(name, []))
                           for name in ("nightly", "publish"))

            runs = _wait_for("SCHEDULED runs of both deployments", SCHEDULED_WAIT_S, scheduled, *watch)
            # made by the server's scheduler from the deployments' schedules; this test creates no run
            every = [r for rs in runs.values() for r in rs]
            assert all(r.auto_scheduled for r in every)
            assert all(r.created_by is not None and r.created_by.type == "SCHEDULE" for r in every)
            assert {r.parameters.get("profile") for r in runs["publish"]} == {"tiny"}
            starts = sorted(r.expected_start_time for r in runs["publish"])
            assert all((b - a).total_seconds() >= INTERVAL_S - 1 for a, b in itertools.pairwise(starts))
            nightly = runs["nightly"]
            assert all(_state(r) == "SCHEDULED" for r in nightly)  # not due yet
            assert {(r.expected_start_time.hour, r.expected_start_time.minute) for r in nightly} == {(2, 0)}

            def completed(runs: dict[str, list[Any]]) -> bool:
                return any(_state(r) == "COMPLETED" for r in runs["publish"])

            runs = _wait_for("COMPLETED publish run", COMPLETED_WAIT_S, completed, *watch)
            assert all(r.auto_scheduled for r in runs["publish"] if _state(r) == "COMPLETED")
        finally:
            serve.terminate()
            try:
                serve.wait(timeout=30)
            except subprocess.TimeoutExpired:
                serve.kill()
                serve.wait(timeout=10)
