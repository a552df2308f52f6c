"""`photoshape ingest ...`: summary table, one line per rejection, exit code 2 on rejections, unmigrated database."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tests.geometry.makers import write_chair_obj, write_png
from tests.imaging.test_exemplar import photo
from tests.imaging.test_hdr import sky, write_hdr
from typer.testing import CliRunner

from photoshape_flow.cli import app

runner = CliRunner()


def test_ingest_commands(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "shapes")
    (tmp_path / "shapes" / "broken.obj").write_text("v 0 0 0\n")
    result = runner.invoke(app, ["ingest", "shapes", str(tmp_path / "shapes"), "--category", "chair", "--no-isolate"])
    assert result.exit_code == 2, result.output  # a rejection fails the command
    assert "ingest shapes" in result.output and "already present" in result.output
    assert "ingest shapes: 2/2 (100%)" in result.output  # progress as plain lines: the runner is no terminal
    flat = " ".join(result.output.split())
    assert "broken.obj: no faces" in result.output.replace("\n", "")
    # how many, and where the reasons are: the lines above and the table's rows
    assert "1 of 2 inputs rejected" in flat and "table shape" in flat and "WHERE status != 'ok'" in flat

    result = runner.invoke(app, ["ingest", "shapes", str(tmp_path / "shapes"), "--no-isolate", "--strict"])
    assert result.exit_code == 2  # the broken file is rejected again; --strict is still accepted
    result = runner.invoke(app, ["ingest", "shapes", str(tmp_path / "shapes"), "--no-isolate", "--allow-rejected"])
    assert result.exit_code == 0, result.output
    assert "1 of 2 inputs rejected" in " ".join(result.output.split())

    write_png(tmp_path / "photos" / "p.png", photo())
    result = runner.invoke(app, ["ingest", "exemplars", str(tmp_path / "photos"), "--size", "64"])
    assert result.exit_code == 0, result.output

    write_png(tmp_path / "mats" / "wood_a" / "albedo.png", np.zeros((4, 4, 3), np.uint8))
    result = runner.invoke(app, ["ingest", "materials", str(tmp_path / "mats"), "--no-previews"])
    assert result.exit_code == 0, result.output

    (tmp_path / "env").mkdir()
    write_hdr(tmp_path / "env" / "a.hdr", sky())
    result = runner.invoke(app, ["ingest", "envmaps", str(tmp_path / "env"), "--split", "val"])
    assert result.exit_code == 0, result.output

    result = runner.invoke(app, ["ingest", "envmaps", str(tmp_path / "env"), "--split", "test"])
    assert result.exit_code != 0 and "--split must be train or val" in result.output

    result = runner.invoke(app, ["ingest", "shapes", str(tmp_path), "--name-filter", "("])
    assert result.exit_code != 0 and "invalid --name-filter" in result.output


def test_ingest_without_rejections_exits_zero(db_url: str, tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "shapes")
    result = runner.invoke(app, ["ingest", "shapes", str(tmp_path / "shapes"), "--category", "chair", "--no-isolate"])
    assert result.exit_code == 0, result.output
    assert "rejected" in result.output and "inputs rejected" not in result.output  # the column, no rejection line


def test_unmigrated_database_is_reported(settings_env: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["ingest", "envmaps", str(tmp_path)])
    assert result.exit_code == 1 and "photoshape db upgrade" in result.output
