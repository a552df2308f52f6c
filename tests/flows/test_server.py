"""Against a real Prefect server: `photoshape serve` registers exactly prefect.yaml's deployments, a burst
of material-added events makes one run, and Dask worker processes fan a stage out."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time
from pathlib import Path
from uuid import UUID

import pytest
import sqlalchemy as sa
from photoshape_flow.flows.deployments import load_declarations

pytestmark = [pytest.mark.prefect, pytest.mark.slow]


def _client_call(env: dict[str, str], fn):  # type: ignore[no-untyped-def]
    from prefect.client.orchestration import get_client
    from prefect.settings import PREFECT_API_URL, temporary_settings

    async def main():  # type: ignore[no-untyped-def]
        async with get_client() as client:
            return await fn(client)

    with temporary_settings({PREFECT_API_URL: env["PREFECT_API_URL"]}):
        return asyncio.run(main())


def test_serve_registers_the_deployments_and_debounces_material_events(
    prefect_server: dict[str, str], tmp_path: Path
) -> None:
    from prefect.client.schemas.filters import DeploymentFilter, DeploymentFilterName

    env = {**os.environ, **prefect_server, "PHOTOSHAPE_DATA_ROOT": str(tmp_path / "data"), "DO_NOT_TRACK": "1"}
    photoshape = str(Path(sys.executable).with_name("photoshape"))
    started = time.time()  # the server is shared: another test's runs of new-materials are not this one's
    serve = subprocess.Popen([photoshape, "serve"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    declared = sorted(d["name"] for d in load_declarations())
    try:
        deadline = time.time() + 120
        names: list[str] = []
        while time.time() < deadline:
            names = sorted(d.name for d in _client_call(env, lambda c: c.read_deployments()))
            if names == declared:
                break
            assert serve.poll() is None, serve.stdout.read().decode()[-2000:] if serve.stdout else ""
            time.sleep(1)
        assert names == declared

        from prefect.events import emit_event
        from prefect.settings import PREFECT_API_URL, temporary_settings

        with temporary_settings({PREFECT_API_URL: env["PREFECT_API_URL"]}):
            for count in (3, 5, 2):  # a bulk import emitting several events
                emit_event(event="photoshape.material.added",
                           resource={"prefect.resource.id": "photoshape.material-set"}, payload={"count": count})

        async def new_material_runs(client):  # type: ignore[no-untyped-def]
            deployment = (await client.read_deployments(
                deployment_filter=DeploymentFilter(name=DeploymentFilterName(any_=["new-materials"]))))[0]
            runs = await client.read_flow_runs(deployment_filter=DeploymentFilter(id={"any_": [deployment.id]}))
            return [r for r in runs if r.created is not None and r.created.timestamp() >= started]

        runs = []
        deadline = time.time() + 60
        while time.time() < deadline and not runs:
            runs = _client_call(env, new_material_runs)
            time.sleep(1)
        time.sleep(5)  # give the later events time to (not) fire again
        runs = _client_call(env, new_material_runs)
        assert len(runs) == 1
        assert runs[0].state_name == "Scheduled"  # debounced: it starts after the schedule_after window
    finally:
        serve.terminate()
        serve.wait(timeout=30)


def test_dask_worker_processes_fan_out_a_stage(prefect_server: dict[str, str], tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.flows.stages import inference
    from prefect.settings import PREFECT_API_URL, temporary_settings
    from prefect_dask import DaskTaskRunner
    from tests.pipeline.aligned import make_aligned_pairs

    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import get_engine, session_scope
    from photoshape_flow.store import BlobStore

    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", str(tmp_path / "data"))
    for key, value in prefect_server.items():
        monkeypatch.setenv(key, value)  # Dask workers inherit the API URL: no ephemeral servers
    get_settings.cache_clear()
    get_engine.cache_clear()
    settings = get_settings()
    migrate.upgrade(settings.resolved_database_url)
    made = make_aligned_pairs(settings.resolved_database_url, BlobStore(settings.blob_root), n_pairs=6)
    runner = DaskTaskRunner(cluster_kwargs={"n_workers": 2, "threads_per_worker": 1, "processes": True})
    with temporary_settings({PREFECT_API_URL: prefect_server["PREFECT_API_URL"]}):
        result = inference.with_options(task_runner=runner)(
            profile="tiny", overrides=["inference.methods=color-match"], batch_size=2)
    assert (result["batches"], result["items"], result["done"], result["failed"]) == (3, 6, 6, 0)
    with session_scope() as session:
        workers = session.execute(sa.select(m.WorkClaim.worker).where(m.WorkClaim.state == "done")).scalars().all()
        pairs = session.execute(sa.select(sa.func.count(sa.distinct(m.Assignment.pair_id)))).scalar_one()
    assert pairs == len(made["pairs"])
    assert len({w.split(":")[-1] for w in workers}) >= 2  # batches ran in more than one worker process
    get_settings.cache_clear()
    get_engine.cache_clear()


def compose_command(service: str) -> tuple[list[str], Path]:
    """docker/compose.yml's command of `service` and its working directory, to run natively here."""
    import yaml
    from tests.conftest import REPO_ROOT

    spec = yaml.safe_load((REPO_ROOT / "docker/compose.yml").read_text())["services"][service]
    command = spec["command"]
    assert spec.get("working_dir") in (None, "/opt/photoshape/src")  # the image's source tree: the checkout here
    return command, REPO_ROOT


def test_compose_deploy_and_worker_commands_run_natively(prefect_server: dict[str, str], tmp_path: Path,
                                                        pg_url: str) -> None:
    """docker/compose.yml's `deploy` service (migrate, work pool, `prefect deploy --all`) and two of its
    `worker` services, run natively on 127.0.0.1 against PostgreSQL: the workers pull the runs of
    prefect.yaml's deployments from the pool and complete them."""
    from tests.pipeline.aligned import make_aligned_pairs

    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import make_engine
    from photoshape_flow.store import BlobStore

    data_root = tmp_path / "data"
    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, **prefect_server, "PHOTOSHAPE_DATA_ROOT": str(data_root), "DO_NOT_TRACK": "1",
           "PHOTOSHAPE_DATABASE_URL": pg_url, "PATH": f"{bin_dir}:{os.environ.get('PATH', '')}"}
    command, cwd = compose_command("deploy")
    deployed = subprocess.run(command, env=env, cwd=cwd, capture_output=True, text=True)
    assert deployed.returncode == 0, deployed.stdout[-2000:] + deployed.stderr[-2000:]
    url = pg_url
    made = make_aligned_pairs(url, BlobStore(data_root / "blobs"), n_pairs=4)

    async def drop_leftovers(client):  # type: ignore[no-untyped-def]
        # runs other tests scheduled on the shared server (e.g. the debounced new-materials run) would
        # now belong to this pool's deployments and be picked up by the workers
        for run in await client.read_flow_runs():
            if run.state is None or not run.state.is_final():
                await client.delete_flow_run(run.id)

    _client_call(env, drop_leftovers)
    worker_command, _ = compose_command("worker")
    polling = {**env, "PREFECT_WORKER_QUERY_SECONDS": "2"}  # the default 10 s poll is idle time in a test
    workers = [subprocess.Popen([*worker_command, "--name", f"w{i}"], env=polling, cwd=tmp_path,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for i in range(2)]
    try:
        async def start_runs(client):  # type: ignore[no-untyped-def]
            # through the API, as `prefect deployment run` does (its CLI start costs seconds a call)
            deployment = await client.read_deployment_by_name("inference/inference")
            return [str((await client.create_flow_run_from_deployment(deployment.id, parameters={
                "profile": "tiny", "overrides": [f"inference.methods={method}"], "batch_size": 2})).id)
                for method in ("color-match", "no-classifier")]

        run_ids: list[str] = _client_call(env, start_runs)
        assert len(run_ids) == 2, run_ids

        async def states(client):  # type: ignore[no-untyped-def]
            # only this test's runs: the server is shared with tests that leave scheduled runs behind
            return [(await client.read_flow_run(UUID(run_id))).state_name for run_id in run_ids]

        deadline = time.time() + 300
        seen: list[str] = []
        while time.time() < deadline:
            seen = _client_call(env, states)
            if all(s in ("Completed", "Failed", "Crashed") for s in seen):
                break
            time.sleep(2)
        assert seen.count("Completed") == 2, seen
    finally:
        for w in workers:
            w.terminate()
        for w in workers:
            try:
                w.wait(timeout=30)
            except subprocess.TimeoutExpired:  # a worker still finishing a run: do not hang the suite
                w.kill()
                w.wait(timeout=30)
    engine = make_engine(url)
    with engine.connect() as conn:
        rows = conn.execute(sa.select(m.Assignment.method, sa.func.count(sa.distinct(m.Assignment.pair_id)))
                            .group_by(m.Assignment.method)).all()
    engine.dispose()
    assert dict(rows) == {"color-match": len(made["pairs"]), "no-classifier": len(made["pairs"])}
