"""`photoshape status` lists held claims (dead holders marked); `photoshape claims release` frees them."""

from __future__ import annotations

from tests.db.claim_holder import HELPER_NAME
from tests.db.test_claims import hold_in_helper
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.db import claims
from photoshape_flow.db.session import session_scope

runner = CliRunner()


def _rows(table: str) -> list[list[str]]:
    """The body rows of a rich table, cells joined across wrapped lines."""
    rows: list[list[str]] = []
    for line in table.splitlines():
        if not line.startswith("│"):
            continue
        cells = [c.strip() for c in line.strip("│").split("│")]
        if cells[0]:
            rows.append(cells)
        else:
            rows[-1] = [f"{a} {b}".strip() for a, b in zip(rows[-1], cells, strict=True)]
    return rows


def test_status_lists_claims_and_release_frees_stale_then_all(db_url: str) -> None:
    with session_scope(db_url) as session:
        claims.claim(session, "publish:pairs", ["1", "2"], worker="w-live", lease_seconds=900)
        claims.claim(session, "publish:pairs", ["3"], worker="w-old", lease_seconds=0.001)
    dead = hold_in_helper(db_url, "training", ["stage"], seconds=60)
    dead.kill()
    dead.wait()
    status = runner.invoke(app, ["status"])
    assert status.exit_code == 0, status.output
    rows = _rows(status.output.split("held claims")[1])
    assert rows[0][:2] == ["publish:pairs", "2"] and rows[0][-1] == "live" and "w-live" in rows[0][2]
    assert rows[1][:2] == ["publish:pairs", "1"] and rows[1][-1] == "expired"
    assert rows[2][:2] == ["training", "1"] and rows[2][-1] == "dead holder"
    assert HELPER_NAME in " ".join(rows[2][2].split())
    listed = _rows(runner.invoke(app, ["claims", "list", "--stage", "training"]).output)
    assert [r[0] for r in listed] == ["training"]

    released = runner.invoke(app, ["claims", "release"])
    assert released.exit_code == 0 and "released 2 stale claims" in released.output
    assert [r[-1] for r in _rows(runner.invoke(app, ["claims", "list"]).output)] == ["live"]
    assert runner.invoke(app, ["claims", "release", "--stale", "--all"]).exit_code == 1
    freed = runner.invoke(app, ["claims", "release", "--all", "--stage", "publish"])
    assert freed.exit_code == 0 and "released 2 held claims of publish" in freed.output
    assert "no claims held" in runner.invoke(app, ["claims", "list"]).output
