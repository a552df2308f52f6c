"""Run the small Node scripts in `export/node/` (glTF validator, headless-Chromium page check).

The Node packages are pinned in ``export/node/package-lock.json`` and installed with
``npm ci --prefix src/photoshape_flow/export/node``. `ProgramMissing` (no node or Chromium: tests
skip with its message) and `PackagesMissing` (npm ci not run: tests fail with the fix) say what is
absent and how to install it.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

NODE_DIR = Path(__file__).resolve().parent / "node"
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser")


class NodeToolsMissing(RuntimeError):
    """node, the npm packages or Chromium are not installed."""


class ProgramMissing(NodeToolsMissing):
    """A system program (node, Chromium) is absent: tests skip on this one."""


class PackagesMissing(NodeToolsMissing):
    """node is there but `npm ci` has not been run: a set-up error, not a reason to skip."""


def node_executable() -> str:
    node = shutil.which("node")
    if node is None:
        raise ProgramMissing("node is not on PATH (apt-get install nodejs; Node >= 20 for playwright-core)")
    return node


def require_package(name: str) -> None:
    node_executable()
    if not (NODE_DIR / "node_modules" / name / "package.json").is_file():
        raise PackagesMissing(f"npm package {name} missing: run `npm ci --prefix {NODE_DIR}`")


def chromium_executable() -> str:
    for candidate in CHROMIUM_CANDIDATES:
        if Path(candidate).is_file():
            return candidate
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        raise ProgramMissing("Chromium not found (apt-get install chromium)")
    return found


def run_script(script: str, *args: str, timeout: float = 120.0) -> dict[str, Any]:
    """Run `node export/node/<script> args...` and parse the JSON it prints on stdout."""
    node = node_executable()
    proc = subprocess.run(
        [node, str(NODE_DIR / script), *args], capture_output=True, text=True, timeout=timeout, cwd=NODE_DIR
    )
    if proc.returncode != 0:
        message = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        raise RuntimeError(f"{script} failed ({proc.returncode}): {message[-1] if message else 'no output'}")
    try:
        return json.loads(proc.stdout)
    except json.JSONDecodeError as exc:
        raise RuntimeError(f"{script}: output is not JSON ({exc})") from exc


def run_script_with_config(script: str, config: dict[str, Any], timeout: float = 120.0) -> dict[str, Any]:
    """`run_script` with `config` passed as the path of a temporary JSON file (too large and nested
    for arguments), removed afterwards."""
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as handle:
        json.dump(config, handle)
        config_path = Path(handle.name)
    try:
        return run_script(script, str(config_path), timeout=timeout)
    finally:
        config_path.unlink(missing_ok=True)
