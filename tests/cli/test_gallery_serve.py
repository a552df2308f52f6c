"""`photoshape gallery --serve` on a tiny database (tests/pipeline/test_publish.py's seed, nothing rendered):
grades from the page are written by the code behind `photoshape grade`, and the command stops on Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
import sqlalchemy as sa
from tests.pipeline.test_publish import seed
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.db.session import session_scope
from photoshape_flow.export.review_server import GradeRejected, GradeRequest
from photoshape_flow.publish.review import DatabaseGrades

PHOTOSHAPE = str(Path(sys.executable).with_name("photoshape"))


def grade_rows(url: str) -> list[tuple]:
    with session_scope(url) as session:
        return [tuple(row) for row in session.execute(sa.text(
            "SELECT pair_id, method_key, label, note, grader FROM grade ORDER BY id"))]


def test_page_grades_are_photoshape_grade_rows(db_url, store, tmp_path):  # type: ignore[no-untyped-def]
    ids = seed(db_url, store, tmp_path)
    key = f"fit:{ids['classifier']}"
    grades = DatabaseGrades("fit")
    now = grades.current()
    assert set(now) == {f"{ids['good']}/{key}", f"{ids['broken']}/{key}"}
    shown = now[f"{ids['good']}/{key}"]
    assert shown["label"] is None and shown["assignment_set"]
    stored = grades.grade(GradeRequest(ids["good"], "good", "close match", key, shown["assignment_set"]))
    assert (stored["label"], stored["note"], stored["grader"], stored["method_key"]) == ("good", "close match",
                                                                                          "user", key)
    again = grades.grade(GradeRequest(ids["good"], "wrong_color", None, key))  # same grader: replaced
    assert again["grade_id"] == stored["grade_id"]
    assert grade_rows(db_url) == [(ids["good"], key, "wrong_color", None, "user")]
    # `photoshape grade` writes the same row (same keys, same grader), and the page reads it back
    result = CliRunner().invoke(app, ["grade", str(ids["good"]), "acceptable", "--note", "from the shell"])
    assert result.exit_code == 0, result.output
    assert grade_rows(db_url) == [(ids["good"], key, "acceptable", "from the shell", "user")]
    assert grades.current()[f"{ids['good']}/{key}"]["label"] == "acceptable"


def test_page_grades_that_cannot_be_written(db_url, store, tmp_path):  # type: ignore[no-untyped-def]
    ids = seed(db_url, store, tmp_path)
    grades = DatabaseGrades("fit", grader="ana")
    cases = [
        (GradeRequest(999, "good"), 400, "pair 999: no such pair"),
        (GradeRequest(ids["good"], "good", method_key="classifier:77"), 400, "no PhotoShape for method"),
        (GradeRequest(ids["good"], "great"), 400, "unknown grade 'great'"),
        # the page's renders show another assignment set than the pair has now: not graded blind
        (GradeRequest(ids["good"], "good", assignment_set="0" * 16), 409, "its materials changed"),
    ]
    for request, status, message in cases:
        with pytest.raises(GradeRejected) as caught:
            grades.grade(request)
        assert caught.value.status == status and message in caught.value.message, caught.value.message
    assert grade_rows(db_url) == []


def test_serve_writes_a_grade_and_stops_on_ctrl_c(db_url, store, tmp_path):  # type: ignore[no-untyped-def]
    ids = seed(db_url, store, tmp_path)
    site = tmp_path / "site"
    proc = subprocess.Popen([PHOTOSHAPE, "gallery", str(site), "--serve", "--port", "0", "--grader", "ana"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=dict(os.environ))
    try:
        lines = []
        while not (lines and lines[-1].startswith("review: serving")):
            line = proc.stdout.readline()
            assert line, "".join(lines)
            lines.append(line)
        url = lines[-1].split(" at ")[1].split()[0]
        assert url.startswith("http://127.0.0.1:")
        page = urllib.request.urlopen(f"{url}candidates.html", timeout=10).read().decode()
        assert '<script src="/api/review.js" defer></script>' in page
        assert "review.js" not in (site / "candidates.html").read_text()
        body = json.dumps({"pair_id": ids["good"], "label": "good"}).encode()
        answer = urllib.request.urlopen(urllib.request.Request(
            f"{url}api/grade", body, {"Content-Type": "application/json"}), timeout=30)
        assert json.loads(answer.read())["grader"] == "ana"
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
    finally:
        proc.kill()
    out = "".join(lines) + out
    assert proc.returncode == 0, out
    assert f"pair {ids['good']} (fit:{ids['classifier']}): graded good by ana" in out
    assert "stopped: 1 grade(s) written" in out and "Traceback" not in out
    page = next((site / "pairs").glob(f"{ids['good']}-*.html")).read_text()
    assert '<span class="grade good">good</span>' in page and "(ana)" in page  # the folder was rewritten


def published_with_grade(url: str, label: str) -> list[tuple]:
    """The documented query of the published PhotoShapes given one grade (docs/data-model.md), for `label`."""
    from tests.db.test_data_model_doc import doc_queries

    query = next(q for q in doc_queries() if "WHERE published AND grade = 'good'" in q)
    with session_scope(url) as session:
        return [(r.pair_id, r.grade) for r in session.execute(sa.text(query.replace("'good'", f"'{label}'")))]


@pytest.mark.render
@pytest.mark.browser
@pytest.mark.slow
def test_review_in_chromium_turn_enlarge_grade_reload_filter(db_url, store, tmp_path):  # type: ignore[no-untyped-def]
    """A person's review session in headless Chromium on two published PhotoShapes: the grade given with a
    key is on the page at once, after a reload, in the grade table and in the documented queries."""
    import threading

    from tests.db.test_data_model_doc import doc_queries

    from photoshape_flow.db import models as m
    from photoshape_flow.export.browser import problems
    from photoshape_flow.export.node_tools import ProgramMissing
    from photoshape_flow.export.review_browser import review_flow
    from photoshape_flow.export.review_server import ReviewServer
    from photoshape_flow.publish.gallery_site import write_gallery_site
    from photoshape_flow.publish.publish import run_publish

    ids = seed(db_url, store, tmp_path)
    with session_scope(db_url) as session:  # give the 'broken' pair's material real maps: both pairs publish
        oak, missing = (session.execute(sa.select(m.Material).where(m.Material.name == name)).scalar_one()
                        for name in ("oak_01", "missing_03"))
        missing.maps = dict(oak.maps)
    assert run_publish(views=1, size=32, spp=2, formats=("glb",)).failed == 0
    site = write_gallery_site(tmp_path / "site", "fit")
    assert site.published == 2
    server = ReviewServer(site.index.parent, DatabaseGrades("fit"), port=0)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        report = review_flow(server.url, label="good", pair=ids["good"])
    except ProgramMissing as exc:
        pytest.skip(str(exc))
    finally:
        server.shutdown()
        server.server_close()
    steps = report["steps"]
    assert "error" not in report, report.get("error")
    assert problems(report) == []  # no console error, failed request or request leaving the server
    assert steps["index"]["summary"] == "review mode: 2 of 2 ungraded; open one to grade it"
    turn = steps["turn"]  # auto-rotate off, then a drag of a quarter of the view's width
    assert abs(turn["after"]["theta"] - turn["before"]["theta"]) > 20, turn
    enlarged = steps["enlarge"]
    assert enlarged["open"] and enlarged["same"] and enlarged["width"] > 500, enlarged
    grade = steps["grade"]
    assert grade["status"] == 200 and grade["body"]["label"] == "good" and grade["shown"].startswith("good")
    assert steps["reload"] == {"shown": "good", "pressed": "good"}
    for view in (steps["ungraded"], steps["ungraded_url"]):  # the filter, and the URL it leaves
        assert {r["pair"]: r["hidden"] for r in view["rows"]} == {ids["good"]: True, ids["broken"]: False}
    assert steps["ungraded"]["count"] == "1" and steps["ungraded"]["url"].endswith("?grade=ungraded")
    key = f"fit:{ids['classifier']}"
    assert grade_rows(db_url) == [(ids["good"], key, "good", None, "user")]
    # grade the other one too: the documented queries return exactly the published PhotoShapes graded good
    assert CliRunner().invoke(app, ["grade", str(ids["broken"]), "wrong_color"]).exit_code == 0
    assert published_with_grade(db_url, "good") == [(ids["good"], "good")]
    assert published_with_grade(db_url, "wrong_color") == [(ids["broken"], "wrong_color")]
    with session_scope(db_url) as session:
        good = [(r.pair_id, r.grade) for r in session.execute(sa.text(doc_queries()[1]))]
    assert good == [(ids["good"], "good")]  # "the good PhotoShapes": graded good (no ungraded one is left)
