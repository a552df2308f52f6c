"""The database side of the gallery's review mode (`export.review_server`, `photoshape gallery --serve`).

`DatabaseGrades` reads the grades of now (`grading.current_grades`, what the gallery shows) and
writes one through `grading.record_grade`, the code behind `photoshape grade`: a grade given on
the page and one given on the command line are the same row, keyed the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from http import HTTPStatus
from typing import Any

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.export.review_server import GradeRejected, GradeRequest
from photoshape_flow.publish.grading import current_grades, graded_photoshape, record_grade
from photoshape_flow.publish.photoshapes import assignment_set_keys, candidate_method_keys


def grade_json(pair_id: int, method_key: str, grade: m.Grade | None, assignment_set: str | None) -> dict[str, Any]:
    """What the review page reads of one PhotoShape: its grade (None: ungraded) and current assignment set."""
    return {"pair_id": pair_id, "method_key": method_key, "assignment_set": assignment_set,
            "label": grade.label if grade else None, "note": grade.note if grade else None,
            "grader": grade.grader if grade else None, "grade_id": grade.id if grade else None}


class DatabaseGrades:
    """Grades of `method`'s PhotoShapes (as `photoshape gallery --method` takes it), given by `grader`.

    One session per call, so the server's request threads share nothing but the engine.
    """

    def __init__(self, method: str, grader: str = "user", settings: Settings | None = None):
        self.method = method
        self.grader = grader or "user"
        self.url = (settings or get_settings()).resolved_database_url

    def current(self) -> Mapping[str, Mapping[str, Any]]:
        """``"<pair_id>/<method_key>"`` -> `grade_json` of every candidate of the method, as now."""
        with session_scope(self.url) as session:
            photoshapes = candidate_method_keys(session, self.method)
            sets = assignment_set_keys(session, photoshapes)
            grades = current_grades(session, photoshapes)
            return {f"{pair_id}/{key}": grade_json(pair_id, key, grades.get((pair_id, key)), sets.get((pair_id, key)))
                    for pair_id, key in photoshapes}

    def grade(self, request: GradeRequest) -> Mapping[str, Any]:
        """Record the grade (`grading.record_grade`); refuses (409) a page whose renders show another
        assignment set than the PhotoShape has now: the grade would be keyed to materials nobody saw."""
        method = request.method_key or self.method
        try:
            with session_scope(self.url) as session:
                method_key, set_key = graded_photoshape(session, request.pair_id, method)
                if request.assignment_set and request.assignment_set != set_key:
                    raise GradeRejected(HTTPStatus.CONFLICT, (
                        f"pair {request.pair_id}: its materials changed since this page's renders were made; "
                        f"`photoshape run publish --pair {request.pair_id}` renders them again, grade it then"))
                grade_id = record_grade(session, request.pair_id, request.label, request.note, self.grader, method)
                return grade_json(request.pair_id, method_key, session.get(m.Grade, grade_id), set_key)
        except ValueError as exc:  # unknown label or pair, or a pair without that PhotoShape: one line
            raise GradeRejected(HTTPStatus.BAD_REQUEST, str(exc)) from None
