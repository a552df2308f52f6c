"""The gallery's review mode: the static site served over HTTP, with grading (`photoshape gallery --serve`).

The folder `write_gallery` wrote stays a static, read-only site. Serving it adds, and only then:

- one script tag in every HTML page sent (`REVIEW_SCRIPT`, rendered from
  ``templates/gallery_review.js``): grade buttons and keys on a PhotoShape's page, the grades of
  now on every page, a way back to the ungraded ones. A page opened from disk has no such tag,
  so it shows no button that could not work;
- ``GET /api/grades``: the current grade of every PhotoShape, read from the database at each
  request (the page reads it on load and patches its badges in);
- ``POST /api/grade`` (JSON: ``pair_id``, ``label``, optional ``note``, ``method_key``,
  ``assignment_set``): one grade, written by the `GradeStore` the server is given (the CLI's
  writes through `publish.grading.record_grade`, the code behind `photoshape grade`).

Why the page reads grades from an endpoint instead of the server rewriting pages after a grade:
the grades of now are one query, always the database's truth (a grade given meanwhile with
`photoshape grade` in another terminal shows on the next reload too), while rewriting the gallery
walks every candidate, copies its images and zips its downloads: work proportional to the
collection for each click, racing the browser that reads the pages being rewritten. The static
pages keep the grades of when they were written; the CLI rewrites the folder once when it stops.

The server binds 127.0.0.1 unless told otherwise, and has no users. A web page elsewhere could
still make a browser send it requests, so a grade is only taken as JSON (a cross-site form cannot
send ``application/json`` without a CORS preflight, which is never answered), from the page's own
origin (``Origin``/``Sec-Fetch-Site``), and every request must name this server in ``Host`` (a
DNS-rebinding page names its own host). This module knows no database: the layer above passes
the `GradeStore`.
"""

from __future__ import annotations

import ipaddress
import json
import socket
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

from photoshape_flow.export.gallery import GRADE_ORDER
from photoshape_flow.export.templating import render
from photoshape_flow.vocab import GRADES

DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 8765
GRADES_PATH, GRADE_PATH, REVIEW_SCRIPT = "/api/grades", "/api/grade", "/api/review.js"
MAX_BODY = 16_384  # bytes of a grade request: a label, a note, two keys
MAX_NOTE = 2_000  # characters of a note
# one key per grade, in the order of the taxonomy (vocab.GRADES): the digit row, left to right
GRADE_KEYS: dict[str, str] = dict(zip(GRADES, "1234567890-=", strict=True))


class GradeRejected(Exception):
    """A grade request the server answers with `status` and one line saying why."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass(frozen=True)
class GradeRequest:
    """One grade as the page sends it: the PhotoShape (pair, method key, the assignment set its
    renders show) and the verdict."""

    pair_id: int
    label: str
    note: str | None = None
    method_key: str | None = None
    assignment_set: str | None = None


class GradeStore(Protocol):
    """Where grades are read and written (`publish.review.DatabaseGrades` in the CLI)."""

    def current(self) -> Mapping[str, Mapping[str, Any]]:
        """``"<pair_id>/<method_key>"`` -> label, note, grader (None when ungraded) and the assignment
        set the PhotoShape shows now, for every PhotoShape the gallery lists."""
        ...

    def grade(self, request: GradeRequest) -> Mapping[str, Any]:
        """Write the grade; the stored row as JSON. Raises `GradeRejected` for an unknown pair or a
        PhotoShape whose materials changed since the page was written."""
        ...


def _optional_text(body: Mapping[str, Any], key: str, limit: int) -> str | None:
    value = body.get(key)
    if value is None:
        return None
    if not isinstance(value, str) or len(value) > limit:
        raise GradeRejected(HTTPStatus.BAD_REQUEST, f"{key}: text of at most {limit} characters")
    return value.strip() or None


def parse_grade_request(raw: bytes, labels: Sequence[str] = GRADES) -> GradeRequest:
    """The body of ``POST /api/grade``, checked; `GradeRejected` (400) names the first problem."""
    try:
        body = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise GradeRejected(HTTPStatus.BAD_REQUEST, "the body is not JSON") from None
    if not isinstance(body, dict):
        raise GradeRejected(HTTPStatus.BAD_REQUEST, "the body must be a JSON object")
    pair_id = body.get("pair_id")
    if isinstance(pair_id, bool) or not isinstance(pair_id, int) or pair_id < 1:
        raise GradeRejected(HTTPStatus.BAD_REQUEST, "pair_id: a pair id (a positive integer) is required")
    label = body.get("label")
    if label not in labels:
        raise GradeRejected(HTTPStatus.BAD_REQUEST, f"unknown grade {label!r}; valid grades: {', '.join(labels)}")
    return GradeRequest(pair_id=pair_id, label=label, note=_optional_text(body, "note", MAX_NOTE),
                        method_key=_optional_text(body, "method_key", 64),
                        assignment_set=_optional_text(body, "assignment_set", 64))


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and localhost: only this machine can connect."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def allowed_hosts(host: str, port: int) -> frozenset[str] | None:
    """The ``Host`` headers a request may carry: this machine's names for a loopback server (a
    DNS-rebinding page carries its own); None (any) when bound to a network address, which anyone
    there reaches directly anyway."""
    if not is_loopback(host):
        return None
    names = {"127.0.0.1", "localhost", "[::1]", host if ":" not in host else f"[{host.strip('[]')}]"}
    return frozenset(f"{name}:{port}".lower() for name in names)


def review_script() -> bytes:
    """The review mode's script: the grade scale, its keys and the badge order, then the code."""
    config = {"grades": [[GRADE_KEYS[g], g] for g in GRADES], "order": GRADE_ORDER,
              "grades_url": GRADES_PATH, "grade_url": GRADE_PATH}
    return render("gallery_review.js", config=config).encode("utf-8")


def with_review_script(page: bytes) -> bytes:
    """An HTML page with the review script's tag before its last ``</body>`` (at its end if none)."""
    tag = f'<script src="{REVIEW_SCRIPT}" defer></script>'.encode()
    at = page.rfind(b"</body>")
    return page + tag if at < 0 else page[:at] + tag + page[at:]


class ReviewServer(ThreadingHTTPServer):
    """The gallery folder `site` on `host:port` (0: any free port) with the grade endpoints.

    `on_grade` is called with each stored grade (the CLI prints a line); `graded` counts them.
    """

    daemon_threads = True  # a request in flight does not hold up Ctrl-C

    def __init__(self, site: str | Path, grades: GradeStore, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 on_grade: Callable[[Mapping[str, Any]], None] | None = None):
        self.site = Path(site).resolve()
        self.grades = grades
        self.on_grade = on_grade
        self.graded = 0
        self.script = review_script()
        if ":" in host.strip("[]"):
            self.address_family = socket.AF_INET6
        super().__init__((host.strip("[]"), port), partial(ReviewHandler, directory=str(self.site)))
        self.host = host.strip("[]")
        self.hosts = allowed_hosts(self.host, self.port)

    @property
    def port(self) -> int:
        return int(self.server_address[1])

    @property
    def url(self) -> str:
        """The index's URL as a browser on this machine opens it."""
        host = self.host
        if host in ("", "0.0.0.0", "::"):
            host = "127.0.0.1"
        return f"http://{f'[{host}]' if ':' in host else host}:{self.port}/"


class ReviewHandler(SimpleHTTPRequestHandler):
    """Static files of the site, HTML with the review script, and the two grade endpoints."""

    server: ReviewServer

    def log_request(self, code: int | str = "-", size: int | str = "-") -> None:
        """Quiet: one line per page, image and script would bury the grade lines the CLI prints."""

    def end_headers(self) -> None:
        self.send_header("X-Content-Type-Options", "nosniff")
        super().end_headers()

    def do_GET(self) -> None:
        if not self._host_allowed():
            return
        path = urlsplit(self.path).path
        if path == GRADES_PATH:
            self._answer(self._grades)
        elif path == REVIEW_SCRIPT:
            self._send(HTTPStatus.OK, self.server.script, "text/javascript; charset=utf-8")
        elif path.startswith("/api/"):
            self._json(HTTPStatus.NOT_FOUND, {"error": f"no such endpoint: {path}"})
        elif (page := self._html_page(path)) is not None:
            self._send(HTTPStatus.OK, with_review_script(page.read_bytes()), "text/html; charset=utf-8")
        else:
            super().do_GET()

    def do_POST(self) -> None:
        if not self._host_allowed():
            return
        if urlsplit(self.path).path != GRADE_PATH:
            self._json(HTTPStatus.NOT_FOUND, {"error": f"POST {GRADE_PATH} only"})
        elif (problem := self._cross_site()) is not None:
            self._json(HTTPStatus.FORBIDDEN, {"error": problem})
        elif self.headers.get_content_type() != "application/json":
            self._json(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, {"error": "send the grade as application/json"})
        else:
            self._answer(self._grade)

    def _grades(self) -> dict[str, Any]:
        return {"grades": dict(self.server.grades.current())}

    def _grade(self) -> dict[str, Any]:
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            raise GradeRejected(HTTPStatus.BAD_REQUEST, "Content-Length is not a number") from None
        if not 0 < length <= MAX_BODY:
            raise GradeRejected(HTTPStatus.REQUEST_ENTITY_TOO_LARGE if length > MAX_BODY else HTTPStatus.BAD_REQUEST,
                                f"a grade is a JSON body of 1 to {MAX_BODY} bytes")
        stored = dict(self.server.grades.grade(parse_grade_request(self.rfile.read(length))))
        self.server.graded += 1
        if self.server.on_grade is not None:
            self.server.on_grade(stored)
        return stored

    def _answer(self, produce: Callable[[], dict[str, Any]]) -> None:
        """`produce`'s JSON (200), a `GradeRejected`'s status and line, or 500 with the error's first line."""
        try:
            self._json(HTTPStatus.OK, produce())
        except GradeRejected as exc:
            self._json(exc.status, {"error": exc.message})
        except Exception as exc:  # the database is down, say: the page shows the line, the server goes on
            self.log_error("%s", str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            self._json(HTTPStatus.INTERNAL_SERVER_ERROR, {"error": f"{type(exc).__name__}: {str(exc)[:200]}"})

    def _host_allowed(self) -> bool:
        hosts = self.server.hosts
        if hosts is None or (self.headers.get("Host") or "").lower() in hosts:
            return True
        self._json(HTTPStatus.MISDIRECTED_REQUEST, {"error": "this server answers to its own address only"})
        return False

    def _cross_site(self) -> str | None:
        """Why a POST is refused as coming from another site's page, or None. A browser sends
        ``Origin`` with every POST; a client without one (curl) is not a page another site runs."""
        origin, fetch_site = self.headers.get("Origin"), self.headers.get("Sec-Fetch-Site")
        if origin is not None and origin.lower() != f"http://{self.headers.get('Host') or ''}".lower():
            return f"cross-origin request refused (Origin {origin})"
        if fetch_site not in (None, "same-origin", "none"):
            return f"cross-site request refused (Sec-Fetch-Site {fetch_site})"
        return None

    def _html_page(self, path: str) -> Path | None:
        """The site's HTML file `path` names (a folder: its index.html), else None."""
        file = Path(self.translate_path(path))  # http.server's: no way out of the site folder
        if path.endswith("/") and file.is_dir():
            file = file / "index.html"
        return file if file.suffix == ".html" and file.is_file() else None

    def _json(self, status: int, body: Mapping[str, Any]) -> None:
        self._send(status, json.dumps(body).encode("utf-8"), "application/json")

    def _send(self, status: int, data: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)
