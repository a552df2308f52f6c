"""Every SQL example in docs/data-model.md runs on both databases and returns what it says."""

from __future__ import annotations

import datetime as dt
import re

import pytest
import sqlalchemy as sa
from sqlalchemy.orm import Session
from tests.conftest import REPO_ROOT
from tests.db.seed import seed

from photoshape_flow.db import migrate
from photoshape_flow.db.session import make_engine


def doc_queries() -> list[str]:
    text = (REPO_ROOT / "docs" / "data-model.md").read_text()
    return [q.strip().rstrip(";") for q in re.findall(r"```sql\n(.*?)```", text, re.S)]


def test_doc_has_examples() -> None:
    assert len(doc_queries()) >= 5


def published_query() -> str:
    """The documented list of published PhotoShapes with their grade (the first example)."""
    query = doc_queries()[0]
    where = query.split("WHERE")[1].split("GROUP BY")[0]
    assert where.strip() == "published" and "grade" in query  # no method named: whatever publish uses
    return query


def seed_published(session: Session, ids: dict[str, int]) -> str:
    """The seeded pair's `fit` PhotoShape as publish leaves it (its exemplar-view render ok), graded
    good after an older grade; the classifier's PhotoShape of the pair stays unpublished. Returns
    the fit method key."""
    from photoshape_flow.db import models as m

    session.get(m.Classifier, ids["classifier"]).status = "ok"
    fit_key = f"fit:{ids['classifier']}"
    session.add(m.Rendering(kind="photoshape", key=f"{ids['pair']}/{fit_key}/exemplar", pair_id=ids["pair"],
                            status="ok", params={}, blobs={}))
    session.add(m.Rendering(kind="photoshape", key=f"{ids['pair']}/classifier:{ids['classifier']}/exemplar",
                            pair_id=ids["pair"], status="failed", params={}, blobs={}))
    session.add(m.Grade(pair_id=ids["pair"], method_key=fit_key, assignment_set="a", label="wrong_material",
                        grader="bob", updated_at=dt.datetime(2026, 1, 1, tzinfo=dt.UTC)))
    session.add(m.Grade(pair_id=ids["pair"], method_key=fit_key, assignment_set="a", label="good",
                        grader="user", updated_at=dt.datetime(2026, 1, 2, tzinfo=dt.UTC)))
    return fit_key


def test_doc_queries_run(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        seed_published(session, seed(session))
    outcomes = []
    with engine.begin() as conn:
        for query in doc_queries():
            result = conn.execute(sa.text(query))
            outcomes.append(len(result.all()) if result.returns_rows else result.rowcount)
    engine.dispose()
    assert all(n >= 1 for n in outcomes), str(list(enumerate(outcomes)))  # every example finds (or updates) rows


def test_published_query_lists_what_publish_rendered_with_its_grade_and_the_gallerys_score(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        ids = seed(session)
        fit_key = seed_published(session, ids)
    with engine.connect() as conn:
        rows = conn.execute(sa.text(published_query())).all()
        good = conn.execute(sa.text(doc_queries()[1])).all()
        confident = conn.execute(sa.text(doc_queries()[2])).all()
        columns = conn.execute(sa.text("SELECT method_key, part_name, confidence, score, ranking_score, published "
                                       "FROM photoshape_candidate WHERE pair_id = :p ORDER BY method_key, part_index"),
                               {"p": ids["pair"]}).all()
    engine.dispose()
    # the fit PhotoShape alone (publish's method), by name, with its newest grade and the gallery's score
    assert [(r.pair_id, r.shape_name, r.exemplar_name, r.method_key, r.grade) for r in rows] == [
        (ids["pair"], "chair", "photo", fit_key, "good")]
    assert rows[0].score == pytest.approx(0.7) and rows[0].weakest_part == pytest.approx(0.7)
    assert [(r.pair_id, r.grade) for r in good] == [(ids["pair"], "good")]
    # the classifier's own ranking, unpublished: every part at least 0.5 (legs 0.9, seat 0.6)
    assert [(r.pair_id, round(r.weakest_part, 3), bool(r.published)) for r in confident] == [(ids["pair"], 0.6, False)]
    by_key = {(r.method_key, r.part_name): r for r in columns}
    classifier = by_key[(f"classifier:{ids['classifier']}", "legs")]
    # the gallery's score: the mean confidence (posterior) over the parts seen (the seat is unobserved)
    assert classifier.score == pytest.approx(0.9) and classifier.ranking_score == pytest.approx(0.3)
    assert by_key[(f"classifier:{ids['classifier']}", "seat")].confidence == pytest.approx(0.6)
    assert bool(by_key[(fit_key, "legs")].published) and not bool(classifier.published)
