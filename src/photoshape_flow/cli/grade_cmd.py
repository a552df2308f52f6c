"""`photoshape grade`: record a person's verdict on a PhotoShape (the paper's result taxonomy)."""

from __future__ import annotations

import typer

from photoshape_flow.cli.common import console, fail, method_or_published, require_database
from photoshape_flow.vocab import GRADES


def grade(
    pair: int = typer.Argument(..., help="Pair id of the PhotoShape."),
    label: str = typer.Argument(..., help=f"One of: {', '.join(GRADES)}."),
    note: str | None = typer.Option(None, "--note", "-n", help="Free-text remark shown in the gallery."),
    grader: str = typer.Option("user", "--grader", "-g", help="Who grades; one grade per grader and PhotoShape."),
    method: str | None = typer.Option(
        None, "--method", "-m",
        help="Whose PhotoShape of the pair: a method (fit, or classifier: the newest classifier's) or an exact "
        "method key such as fit:3. Default: the collection's publish.method (its last run's).",
    ),
) -> None:
    """Grade the pair's PhotoShape as it is now; re-grading it by the same grader replaces the earlier grade.

    The grade is keyed by what it was given to (the method key and the assignment set shown), so a
    new classifier's PhotoShape of the pair starts ungraded and the old grade stays. Queryable in
    SQL: SELECT pair_id, method_key, label, grader FROM grade.
    """
    require_database()
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.publish.grading import record_grade

    method = method_or_published(method)
    if label not in GRADES:
        fail(f"unknown grade {label!r}; valid grades: {', '.join(GRADES)}")
    try:
        with session_scope(get_settings().resolved_database_url) as session:
            grade_id = record_grade(session, pair, label, note, grader, method)
            method_key = session.get(m.Grade, grade_id).method_key
    except ValueError as exc:
        fail(str(exc))
    console.print(f"pair {pair} ({method_key}): graded {label} by {grader} (grade {grade_id})", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("grade")(grade)
