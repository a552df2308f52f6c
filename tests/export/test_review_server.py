"""The review server's HTTP side (`export.review_server`) with an in-memory grade store: what it serves,
what it takes as a grade and what it refuses. The database side is tests/cli/test_gallery_serve.py."""

from __future__ import annotations

import http.client
import json
import threading
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest

from photoshape_flow.export.review_server import (
    DEFAULT_HOST,
    GRADE_KEYS,
    GradeRejected,
    GradeRequest,
    ReviewServer,
    allowed_hosts,
    is_loopback,
    parse_grade_request,
)
from photoshape_flow.vocab import GRADES


class MemoryGrades:
    """Pair 1 (method key fit:1, assignment set "s1") is the only PhotoShape; grades replace each other."""

    def __init__(self) -> None:
        self.written: list[GradeRequest] = []

    def current(self) -> Mapping[str, Mapping[str, Any]]:
        last = self.written[-1] if self.written else None
        return {"1/fit:1": {"label": last.label if last else None, "note": last.note if last else None,
                            "assignment_set": "s1"}}

    def grade(self, request: GradeRequest) -> Mapping[str, Any]:
        if request.pair_id != 1:
            raise GradeRejected(400, f"pair {request.pair_id}: no such pair")
        self.written.append(request)
        return {"pair_id": 1, "method_key": "fit:1", "label": request.label, "note": request.note, "grader": "user"}


@pytest.fixture
def site(tmp_path: Path) -> Path:
    root = tmp_path / "site"
    (root / "pairs").mkdir(parents=True)
    (root / "index.html").write_text("<html><body><p>index</p></body></html>")
    (root / "pairs" / "1-fit-1.html").write_text("<html><body>pair</body></html>")
    (root / "style.css").write_text("p{}")
    return root


@pytest.fixture
def served(site: Path) -> Iterator[tuple[ReviewServer, MemoryGrades]]:
    grades = MemoryGrades()
    server = ReviewServer(site, grades, port=0)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield server, grades
    server.shutdown()
    server.server_close()
    thread.join(5)


def request(server: ReviewServer, method: str, path: str, body: object = None,
            headers: Mapping[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    sent = {"Content-Type": "application/json", **(headers or {})} if method == "POST" else dict(headers or {})
    conn.request(method, path, body=data, headers=sent)
    response = conn.getresponse()
    out = response.status, {k.lower(): v for k, v in response.getheaders()}, response.read()
    conn.close()
    return out


def post_grade(server: ReviewServer, body: object, **headers: str) -> tuple[int, Any]:
    origin = {"Origin": f"http://127.0.0.1:{server.port}"}
    status, _, data = request(server, "POST", "/api/grade", body, {**origin, **headers})
    return status, json.loads(data)


def test_binds_loopback_by_default(site: Path) -> None:
    server = ReviewServer(site, MemoryGrades(), port=0)
    try:
        assert DEFAULT_HOST == "127.0.0.1" and server.server_address[0] == "127.0.0.1"
        assert server.url == f"http://127.0.0.1:{server.port}/" and server.port > 0
    finally:
        server.server_close()


def test_pages_get_the_review_script_and_files_on_disk_stay_static(served, site: Path) -> None:
    server, _ = served
    status, headers, page = request(server, "GET", "/")
    assert status == 200 and headers["content-type"].startswith("text/html")
    assert page == b'<html><body><p>index</p><script src="/api/review.js" defer></script></body></html>'
    status, _, pair = request(server, "GET", "/pairs/1-fit-1.html")
    assert status == 200 and b"/api/review.js" in pair
    assert "review.js" not in (site / "index.html").read_text()  # from file:// the site stays read-only
    status, headers, script = request(server, "GET", "/api/review.js")
    assert status == 200 and headers["content-type"].startswith("text/javascript")
    assert b'["1", "good"]' in script and b'["=", "not_sure"]' in script  # the scale and its keys
    status, _, css = request(server, "GET", "/style.css")
    assert status == 200 and css == b"p{}"
    assert request(server, "GET", "/../secret.txt")[0] == 404
    assert request(server, "GET", "/api/nothing")[0] == 404


def test_a_grade_is_written_read_back_and_replaced(served) -> None:
    server, grades = served
    status, body = post_grade(server, {"pair_id": 1, "method_key": "fit:1", "label": "good", "note": " close "})
    assert status == 200 and body["label"] == "good" and body["note"] == "close"
    status, _, data = request(server, "GET", "/api/grades")
    assert status == 200 and json.loads(data)["grades"]["1/fit:1"]["label"] == "good"
    status, body = post_grade(server, {"pair_id": 1, "label": "wrong_color"})  # re-grade: the store replaces
    assert status == 200 and body["label"] == "wrong_color" and body["note"] is None
    assert [g.label for g in grades.written] == ["good", "wrong_color"] and server.graded == 2


@pytest.mark.parametrize(("body", "message"), [
    ({"pair_id": 1, "label": "great"}, "unknown grade 'great'; valid grades: good, acceptable"),
    ({"label": "good"}, "pair_id: a pair id (a positive integer) is required"),
    ({"pair_id": "1", "label": "good"}, "pair_id: a pair id"),
    ({"pair_id": True, "label": "good"}, "pair_id: a pair id"),
    ({"pair_id": 1, "label": "good", "note": 3}, "note: text of at most 2000 characters"),
    ({"pair_id": 1, "label": "good", "note": "x" * 2001}, "note: text of at most 2000 characters"),
    ([1, "good"], "the body must be a JSON object"),
    (b"{not json", "the body is not JSON"),
    ({"pair_id": 999, "label": "good"}, "pair 999: no such pair"),
])
def test_bad_grades_are_400_with_one_line(served, body: object, message: str) -> None:
    server, grades = served
    status, answer = post_grade(server, body)
    assert status == 400 and answer["error"].startswith(message) and "\n" not in answer["error"]
    assert grades.written == [] and server.graded == 0


def test_cross_site_posts_and_foreign_hosts_are_refused(served) -> None:
    server, grades = served
    good = {"pair_id": 1, "label": "good"}
    assert post_grade(server, good, Origin="http://evil.example")[0] == 403
    assert post_grade(server, good, Origin="null")[0] == 403  # a file:// page or a sandboxed frame
    assert post_grade(server, good, **{"Sec-Fetch-Site": "cross-site"})[0] == 403
    # a form another site posts cannot be JSON
    status, _, _ = request(server, "POST", "/api/grade", b"pair_id=1&label=good",
                           {"Content-Type": "application/x-www-form-urlencoded"})
    assert status == 415
    # DNS rebinding: a page of evil.example resolved to 127.0.0.1 sends its own Host
    assert request(server, "GET", "/api/grades", headers={"Host": f"evil.example:{server.port}"})[0] == 421
    assert post_grade(server, good, Host=f"evil.example:{server.port}", Origin=f"http://evil.example:{server.port}"
                      )[0] == 421
    assert request(server, "GET", "/api/grades", headers={"Host": f"localhost:{server.port}"})[0] == 200
    assert grades.written == []
    status, _, _ = request(server, "POST", "/api/grade", b"x" * 20_000)
    assert status == 413


def test_request_parsing_and_addresses() -> None:
    parsed = parse_grade_request(b'{"pair_id": 3, "label": "limitation", "method_key": "fit:2", "note": ""}')
    assert parsed == GradeRequest(pair_id=3, label="limitation", note=None, method_key="fit:2")
    assert list(GRADE_KEYS) == list(GRADES) and len(set(GRADE_KEYS.values())) == len(GRADES)
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")
    assert allowed_hosts("0.0.0.0", 8765) is None
    assert allowed_hosts("127.0.0.1", 8765) == {"127.0.0.1:8765", "localhost:8765", "[::1]:8765"}
