"""`photoshape doctor` on a blob store at a URL: shown with its credentials masked, failures with a fix."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.cli.doctor_cmd import check_blob_store
from photoshape_flow.config import get_settings

SECRET = "wJalrXUtnFEMI-K7MDENG"


def _blob_root(monkeypatch: pytest.MonkeyPatch, value: str) -> None:
    monkeypatch.setenv("PHOTOSHAPE_BLOB_ROOT", value)
    get_settings.cache_clear()


def test_doctor_masks_the_blob_store_credentials(settings_env: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _blob_root(monkeypatch, f"s3://AKIAEXAMPLE:{SECRET}@bucket/blobs")  # s3fs is not installed here
    check = check_blob_store()
    assert not check.ok and check.detail.startswith("s3://AKIAEXAMPLE:***@bucket/blobs: ")
    assert "s3fs" in check.detail + check.hint and SECRET not in check.detail
    result = CliRunner().invoke(app, ["doctor"])
    assert result.exit_code == 1 and "blob store" in result.output and SECRET not in "".join(result.output.split())


def test_doctor_reaches_a_file_url_store(settings_env: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _blob_root(monkeypatch, (tmp_path / "shared").as_uri())
    check = check_blob_store()
    assert check.ok and "reachable" in check.detail and str(settings_env / "cache" / "blobs") in check.detail
    _blob_root(monkeypatch, str(tmp_path / "folder"))
    assert check_blob_store().detail.endswith("(local folder)")
