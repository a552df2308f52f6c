"""The schema's migrations: one head, reversible with data present, in step with the models."""

from __future__ import annotations

import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy.orm import Session
from tests.db.seed import seed

from photoshape_flow.db import migrate
from photoshape_flow.db.base import Base
from photoshape_flow.db.session import make_engine


def test_single_head() -> None:
    assert len(migrate.heads()) == 1


def test_upgrade_downgrade_upgrade_with_rows(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        seed(session)
    migrate.downgrade(any_db_url, "base")
    with engine.connect() as conn:
        assert "shape" not in sa.inspect(conn).get_table_names()
    migrate.upgrade(any_db_url)
    with Session(engine) as session, session.begin():
        ids = seed(session, suffix="-2")
    with engine.connect() as conn:
        rows = conn.execute(
            sa.text("SELECT part_name, material_name FROM photoshape_candidate WHERE pair_id = :p AND method = "
                    "'classifier' ORDER BY part_index"),
            {"p": ids["pair"]},
        ).all()
    assert [tuple(r) for r in rows] == [("legs", "oak-2"), ("seat", "leather-2")]
    assert migrate.current_revision(any_db_url) == migrate.heads()[0]
    engine.dispose()


def test_models_and_migrations_agree(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with engine.connect() as conn:
        context = MigrationContext.configure(conn, opts={"compare_type": True})
        diff = compare_metadata(context, Base.metadata)
    engine.dispose()
    assert diff == []


def test_exemplar_match_revision_drops_the_old_reverse_index_rows(any_db_url: str) -> None:
    """The `topk:` exemplar_feature rows (blobs the migration cannot read) go; real descriptors stay."""
    migrate.upgrade(any_db_url, "80193f30daa2")
    engine = make_engine(any_db_url)
    with engine.begin() as conn:
        eid = conn.execute(
            sa.text("INSERT INTO exemplar (source, source_id, meta, status, exclude, params_hash) "
                    "VALUES ('test', 'photo', '{}', 'ok', FALSE, '') RETURNING id")
        ).scalar_one()
        for descriptor in ("hog-insensitive9", "dedupe-hog", "topk:hog-insensitive9:1", "topk:hog-all31:2:chair"):
            conn.execute(
                sa.text("INSERT INTO exemplar_feature (exemplar_id, descriptor, status, params_hash) "
                        "VALUES (:e, :d, 'ok', '')"),
                {"e": eid, "d": descriptor},
            )
    migrate.upgrade(any_db_url)
    with engine.connect() as conn:
        left = conn.execute(sa.text("SELECT descriptor FROM exemplar_feature ORDER BY descriptor")).scalars().all()
        matches = conn.execute(sa.text("SELECT COUNT(*) FROM exemplar_match")).scalar_one()
    engine.dispose()
    assert left == ["dedupe-hog", "hog-insensitive9"] and matches == 0


def test_grade_keys_revision_backfills_from_the_published_method(any_db_url: str) -> None:
    """Grades of a published pair get its method and assignment-set key; others stay legacy (NULL)."""
    from photoshape_flow.publish.photoshapes import assignment_set_keys

    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        ids = seed(session)  # one grade on the pair, no render yet
    method_key = f"classifier:{ids['classifier']}"
    grade_keys = sa.text("SELECT method_key, assignment_set FROM grade")
    migrate.downgrade(any_db_url, "90238d22ce60")
    migrate.upgrade(any_db_url)
    with engine.connect() as conn:
        assert conn.execute(grade_keys).one() == (None, None)  # never published: a legacy grade
    migrate.downgrade(any_db_url, "90238d22ce60")
    with engine.begin() as conn:
        conn.execute(sa.text(
            "INSERT INTO rendering (kind, key, pair_id, params, blobs, status, params_hash) "
            "VALUES ('photoshape', :k, :p, '{}', '{}', 'ok', '')"), {"k": f"{ids['pair']}/{method_key}/exemplar",
                                                                   "p": ids["pair"]})
    migrate.upgrade(any_db_url)
    with Session(engine) as session:
        expected = assignment_set_keys(session, [(ids["pair"], method_key)])[(ids["pair"], method_key)]
        assert tuple(session.execute(grade_keys).one()) == (method_key, expected)
    engine.dispose()
