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
    for service in ("postgres", "prefect-server", "serve", "worker"):
        assert f"{service}:" in out.stdout


def test_image_and_readme_share_one_setup_script() -> None:
    dockerfile = (REPO_ROOT / "docker/Dockerfile").read_text()
    assert re.search(r"^RUN bash scripts/setup\.sh", dockerfile, re.M)
    makefile = (REPO_ROOT / "Makefile").read_text()
    assert "bash scripts/setup.sh" in makefile
    readme = (REPO_ROOT / "README.md").read_text()
    commands = re.findall(r"^\s*(make \w+)\s*$", readme, re.M)
    assert "make demo" in commands and "make test" in commands
    for target in ("demo", "test"):
        assert re.search(rf"^{target}: setup$", makefile, re.M)  # both commands set everything up first
    assert "make test" in (REPO_ROOT / ".ci/run").read_text()
