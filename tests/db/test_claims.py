"""Work claims: a claim is exclusive until its lease expires; done items are skipped unless stale."""

from __future__ import annotations

import multiprocessing as mp
import time

from sqlalchemy.orm import Session

from photoshape_flow.db import claims, migrate
from photoshape_flow.db.session import make_engine


def _claim(url: str, keys: list[str], worker: str, lease: float = 60, params_hash: str = "h") -> list[str]:
    engine = make_engine(url)
    with Session(engine) as session, session.begin():
        won = claims.claim(session, "stage", keys, worker=worker, lease_seconds=lease, params_hash=params_hash)
    engine.dispose()
    return won


def test_claim_is_exclusive_until_lease_expires(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    keys = ["a", "b", "c"]
    assert _claim(any_db_url, keys, "w1", lease=0.5) == keys
    assert _claim(any_db_url, keys, "w2") == []
    time.sleep(0.7)
    assert _claim(any_db_url, keys, "w2") == keys


def test_done_items_are_skipped_unless_params_change(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    assert _claim(any_db_url, ["a", "b"], "w1") == ["a", "b"]
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        claims.complete(session, "stage", ["a"], worker="w1")
        claims.fail(session, "stage", "b", "boom", worker="w1")
    assert _claim(any_db_url, ["a", "b"], "w2") == []
    assert _claim(any_db_url, ["a", "b"], "w2", params_hash="h2") == ["a", "b"]
    with Session(engine) as session:
        assert claims.counts(session, "stage") == {("stage", "claimed"): 2}
    engine.dispose()


def _worker(url: str, keys: list[str], name: str, queue: mp.Queue) -> None:
    won: list[str] = []
    for i in range(0, len(keys), 5):
        won += _claim(url, keys[i : i + 5], name)
    queue.put(won)


def test_four_processes_never_claim_an_item_twice(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    keys = [f"item-{i:03d}" for i in range(80)]
    ctx = mp.get_context("spawn")
    queue: mp.Queue = ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(any_db_url, keys, f"w{i}", queue)) for i in range(4)]
    for p in procs:
        p.start()
    results = [queue.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(timeout=60)
    claimed = [k for r in results for k in r]
    assert sorted(claimed) == keys  # each item exactly once, none lost
