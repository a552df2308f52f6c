"""Every SQL example in docs/data-model.md runs on both databases and returns what it says."""

from __future__ import annotations

import re

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


def test_doc_queries_run(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        ids = seed(session)
        from photoshape_flow.db import models as m

        session.get(m.Classifier, ids["classifier"]).status = "ok"
    outcomes = []
    with engine.begin() as conn:
        for query in doc_queries():
            result = conn.execute(sa.text(query))
            outcomes.append(len(result.all()) if result.returns_rows else result.rowcount)
    engine.dispose()
    assert all(n >= 1 for n in outcomes), outcomes  # every example finds (or updates) the seeded rows


def test_candidate_query_lists_the_seeded_photoshape(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        ids = seed(session)
        from photoshape_flow.db import models as m

        session.get(m.Classifier, ids["classifier"]).status = "ok"
    with engine.connect() as conn:
        rows = conn.execute(sa.text(doc_queries()[0])).all()
    engine.dispose()
    assert [(r.pair_id, round(r.weakest_part, 3)) for r in rows] == [(ids["pair"], 0.6)]
