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


def test_db_upgrade_current_and_status(settings_env: Path) -> None:
    result = invoke("status")
    assert result.exit_code == 1 and "not migrated" in result.output
    assert invoke("db", "upgrade").exit_code == 0
    current = invoke("db", "current")
    assert "up to date" in current.output
    status = invoke("status")
    assert status.exit_code == 0
    for stage in ("ingest", "coarse-alignment", "fine-alignment", "substances", "training-renders", "training",
                  "inference", "publish"):
        assert stage in status.output
    assert invoke("db", "downgrade", "base").exit_code == 0
    assert "behind head" in invoke("db", "current").output


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
