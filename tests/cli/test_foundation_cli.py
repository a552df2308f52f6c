"""The foundation verbs: help, db, status, gc, doctor."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from photoshape_flow.cli import app

runner = CliRunner()


def invoke(*args: str):  # type: ignore[no-untyped-def]
    return runner.invoke(app, list(args), catch_exceptions=False)


def test_help_lists_the_verbs_with_one_line_help() -> None:
    result = invoke("--help")
    assert result.exit_code == 0
    for verb in ("db", "status", "doctor", "gc"):
        assert verb in result.output


def test_version_prints_the_installed_version() -> None:
    from importlib.metadata import version

    result = invoke("--version")
    assert result.exit_code == 0, result.output
    assert result.output.strip() == f"photoshape_flow {version('photoshape_flow')}"


def test_db_upgrade_says_when_it_creates_a_new_database(settings_env: Path) -> None:
    result = invoke("db", "upgrade")
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if "new database" in line]
    assert lines == [f"created a new database at {(settings_env / 'photoshape.db').resolve()} (it was empty; "
                     "check PHOTOSHAPE_DATA_ROOT if you meant an existing one)"]
    again = invoke("db", "upgrade")  # an existing database: no such line
    assert again.exit_code == 0 and "new database" not in again.output


def test_db_upgrade_current_and_status(settings_env: Path) -> None:
    result = invoke("status")
    assert result.exit_code == 1 and "not migrated" in result.output
    upgraded = invoke("db", "upgrade")  # `status` made the file, but it is still a new (empty) database
    assert upgraded.exit_code == 0 and "created a new database at" in upgraded.output
    current = invoke("db", "current")
    assert "up to date" in current.output
    status = invoke("status")
    assert status.exit_code == 0
    flat = " ".join(status.output.split())
    assert "counts assume profile default (no run recorded yet; publish: pairs up to rank 12)" in flat
    assert "rejected" in flat
    for stage in ("ingest", "coarse-alignment", "fine-alignment", "substances", "training-renders", "training",
                  "inference", "fit", "publish"):
        assert stage in status.output
    assert invoke("db", "downgrade", "base").exit_code == 0
    assert "behind head" in invoke("db", "current").output


def test_run_all_on_an_empty_collection_fails_in_one_line_naming_the_stage(settings_env: Path) -> None:
    """Nothing ingested yet: the run stops at the first stage that cannot work (no shape to render), says which
    and why in one line, records the run failed, and prints no traceback."""
    assert invoke("db", "upgrade").exit_code == 0
    result = invoke("run", "all", "--profile", "tiny")
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    flat = " ".join(result.output.split())
    assert "failed: substances: no usable shape" in flat, result.output  # its bootstrap renders
    status = " ".join(invoke("status").output.split())
    assert "running" not in status.replace("running: 0", "")


def test_gc_keeps_referenced_blobs(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    import os
    import time

    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope

    kept = store.put_bytes(b"mesh", "npz")
    dropped = store.put_bytes(b"orphan", "png")
    old = time.time() - 10_000
    for ref in (kept, dropped):
        os.utime(store.path(ref), (old, old))
    with session_scope(db_url) as session:
        session.add(m.Material(name="oak", substance="wood", maps={"albedo": kept}))
    result = invoke("gc")
    assert result.exit_code == 0 and "removed 1" in result.output
    assert store.exists(kept) and not store.exists(dropped)


def test_doctor_reports_each_check(db_url: str) -> None:
    result = runner.invoke(app, ["doctor"])
    for name in ("python", "database", "schema", "data root", "free disk", "torch"):
        assert name in result.output


def test_read_verbs_on_an_unmigrated_database_fail_with_one_line(settings_env: Path, tmp_path: Path) -> None:
    photo = tmp_path / "photo.png"
    photo.write_bytes(b"not read before the database check")
    for args in (("gallery", str(tmp_path / "site")), ("export", "--out", str(tmp_path / "out")),
                 ("grade", "1", "good"), ("retrieve", str(photo), "--mask", str(photo)),
                 ("eval", str(tmp_path / "gt.json"))):
        result = invoke(*args)
        assert result.exit_code == 1, args
        assert "not migrated; run `photoshape db upgrade`" in result.output.replace("\n", " "), args
        assert "Traceback" not in result.output, args
