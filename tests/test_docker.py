"""What can be tested without a Docker engine: the compose file validates, and the image is built by
the same set-up script the README's commands run."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import pytest
from tests.conftest import REPO_ROOT


def test_compose_file_validates() -> None:
    if shutil.which("docker-compose") is None:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("docker-compose is missing (scripts/setup.sh installs it)")
        pytest.skip("docker-compose not installed")
    env = {**os.environ, "POSTGRES_PASSWORD": "test"}
    out = subprocess.run(["docker-compose", "-f", str(REPO_ROOT / "docker/compose.yml"), "config"],
                         capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    for service in ("postgres", "prefect-server", "deploy", "worker"):
        assert f"{service}:" in out.stdout


def test_compose_binds_localhost_and_the_build_context_is_small() -> None:
    """Only the Prefect UI is published, on 127.0.0.1 unless PREFECT_PUBLISH says otherwise; the build
    context leaves out environments, data and VCS history."""
    import yaml

    services = yaml.safe_load((REPO_ROOT / "docker/compose.yml").read_text())["services"]
    published = {name: spec["ports"] for name, spec in services.items() if spec.get("ports")}
    assert published == {"prefect-server": ["${PREFECT_PUBLISH:-127.0.0.1}:4200:4200"]}
    assert services["worker"]["depends_on"] == {"deploy": {"condition": "service_completed_successfully"}}
    ignored = (REPO_ROOT / ".dockerignore").read_text().split()
    assert {".git", ".venv", "photoshape-data", "**/node_modules"} <= set(ignored)


def test_image_and_readme_share_one_setup_script() -> None:
    dockerfile = (REPO_ROOT / "docker/Dockerfile").read_text()
    assert re.search(r"^RUN SETUP_MODE=runtime bash scripts/setup\.sh", dockerfile, re.M)  # no test tools
    makefile = (REPO_ROOT / "Makefile").read_text()
    assert "bash scripts/setup.sh" in makefile
    readme = (REPO_ROOT / "README.md").read_text()
    commands = re.findall(r"^\s*(make \w+)\s*$", readme, re.M)
    assert "make demo" in commands and "make test" in commands
    for target in ("demo", "test"):
        assert re.search(rf"^{target}: setup$", makefile, re.M)  # both commands set everything up first
    assert "make test" in (REPO_ROOT / ".ci/run").read_text()


def _docker_engine() -> bool:
    if shutil.which("docker") is None or shutil.which("docker-compose") is None:
        return False
    return subprocess.run(["docker", "info"], capture_output=True).returncode == 0


@pytest.mark.slow
def test_compose_stack_schedules_the_nightly_runs(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """With a Docker engine: the stack comes up, `deploy` registers prefect.yaml in the pool and the
    server's scheduler lists upcoming `nightly` runs (auto-scheduled). No engine here: skipped; the
    services' commands are run natively by tests/flows/test_server.py instead."""
    if not _docker_engine():
        pytest.skip("no Docker engine on this machine")
    import json
    import time
    import urllib.request

    env = {**os.environ, "POSTGRES_PASSWORD": "test", "COMPOSE_PROJECT_NAME": f"psf{os.getpid()}"}
    compose = ["docker-compose", "-f", str(REPO_ROOT / "docker/compose.yml")]
    try:
        subprocess.run([*compose, "up", "-d", "--build"], env=env, check=True, capture_output=True, timeout=3600)
        deadline, runs = time.time() + 600, []
        while time.time() < deadline and not runs:
            query = {"flow_runs": {"state": {"type": {"any_": ["SCHEDULED"]}}}}
            request = urllib.request.Request("http://127.0.0.1:4200/api/flow_runs/filter", method="POST",
                                             data=json.dumps(query).encode(),
                                             headers={"Content-Type": "application/json"})
            try:
                with urllib.request.urlopen(request, timeout=5) as response:
                    runs = [r for r in json.load(response) if r.get("auto_scheduled")]
            except OSError:
                pass
            time.sleep(5)
        assert runs, "no auto-scheduled run appeared"
    finally:
        subprocess.run([*compose, "down", "-v"], env=env, capture_output=True, timeout=600)
