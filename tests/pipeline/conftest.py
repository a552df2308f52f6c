"""Fixtures shared by the pipeline's whole-run tests (kill points, concurrent runs)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from tests.conftest import data_root_with_inbox
from tests.pipeline.whole_runs import run_all, snapshot


@pytest.fixture(scope="session")
def reference(tiny_demo: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """One uninterrupted `run all` on SQLite (its data root and `snapshot`): what every resumed run reproduces."""
    root = data_root_with_inbox(tmp_path_factory.mktemp("kill-reference") / "data", tiny_demo)
    done = run_all(root, None)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return root, snapshot(f"sqlite:///{root / 'photoshape.db'}")
