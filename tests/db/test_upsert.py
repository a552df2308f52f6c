"""Idempotent writes on the natural key, on both databases."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import migrate
from photoshape_flow.db import models as m
from photoshape_flow.db.session import make_engine
from photoshape_flow.db.upsert import upsert


def test_upsert_twice_changes_nothing_and_updates_on_new_values(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    row = {"name": "oak", "substance": "wood", "default_scale": 0.3, "maps": {"albedo": "a" * 64 + ".png"}}
    with Session(engine) as session, session.begin():
        first = upsert(session, m.Material, row, key=["name"])
    with Session(engine) as session, session.begin():
        second = upsert(session, m.Material, row, key=["name"])
    assert first == second
    with Session(engine) as session, session.begin():
        third = upsert(session, m.Material, {**row, "default_scale": 0.5}, key=["name"])
        assert third == first
    with Session(engine) as session:
        rows = session.execute(sa.select(m.Material.name, m.Material.default_scale)).all()
    assert [tuple(r) for r in rows] == [("oak", 0.5)]
    engine.dispose()


def test_insert_or_keep_returns_existing_id(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        a = upsert(session, m.Envmap, {"name": "studio", "split": "train"}, key=["name"], update=[])
        b = upsert(session, m.Envmap, {"name": "studio", "split": "val"}, key=["name"], update=[])
    assert a == b
    with Session(engine) as session:
        assert session.execute(sa.select(m.Envmap.split)).scalar_one() == "train"
    engine.dispose()
