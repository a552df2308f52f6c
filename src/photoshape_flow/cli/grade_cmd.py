"""`photoshape grade`: record a person's verdict on a PhotoShape (the paper's result taxonomy)."""

from __future__ import annotations

import typer

from photoshape_flow.cli.common import console, fail, require_database
from photoshape_flow.vocab import GRADES


def grade(
    pair: int = typer.Argument(..., help="Pair id of the PhotoShape."),
    label: str = typer.Argument(..., help=f"One of: {', '.join(GRADES)}."),
    note: str | None = typer.Option(None, "--note", "-n", help="Free-text remark shown in the gallery."),
    grader: str = typer.Option("user", "--grader", "-g", help="Who grades; one grade per grader and pair."),
) -> None:
    """Grade a PhotoShape; re-grading by the same grader replaces the earlier grade.

    Grades are queryable in SQL: SELECT * FROM grade JOIN photoshape_candidate USING (pair_id).
    """
    require_database()
    from photoshape_flow.config import get_settings
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.pipeline.grading import record_grade

    if label not in GRADES:
        fail(f"unknown grade {label!r}; valid grades: {', '.join(GRADES)}")
    try:
        with session_scope(get_settings().resolved_database_url) as session:
            grade_id = record_grade(session, pair, label, note, grader)
    except ValueError as exc:
        fail(str(exc))
    console.print(f"pair {pair}: graded {label} by {grader} (grade {grade_id})")


def register(app: typer.Typer) -> None:
    app.command("grade")(grade)
