"""Work claims: exclusive until the lease expires or the holder dies; renewed by a heartbeat; done items
are skipped unless stale."""

from __future__ import annotations

import multiprocessing as mp
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.db import claims, holder, migrate
from photoshape_flow.db.heartbeat import Heartbeat
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


def _worker(url: str, keys: list[str], name: str, queue: mp.Queue, stop: Any) -> None:
    won: list[str] = []
    for i in range(0, len(keys), 5):
        won += _claim(url, keys[i : i + 5], name)
    queue.put(won)
    stop.wait(120)  # stay alive: a finished process's claims would be free (its holder is dead)


def test_four_processes_never_claim_an_item_twice(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    keys = [f"item-{i:03d}" for i in range(80)]
    ctx = mp.get_context("spawn")
    queue: mp.Queue = ctx.Queue()
    stop = ctx.Event()
    procs = [ctx.Process(target=_worker, args=(any_db_url, keys, f"w{i}", queue, stop)) for i in range(4)]
    for p in procs:
        p.start()
    results = [queue.get(timeout=120) for _ in procs]
    stop.set()
    for p in procs:
        p.join(timeout=60)
    claimed = [k for r in results for k in r]
    assert sorted(claimed) == keys  # each item exactly once, none lost


HOLDER_SCRIPT = Path(__file__).with_name("claim_holder.py")


def hold_in_helper(url: str, stage: str, keys: list[str], seconds: float, release: bool = False) -> subprocess.Popen:
    """Start a separate worker process holding `keys` of `stage`; returns once it has claimed them."""
    helper = subprocess.Popen([sys.executable, str(HOLDER_SCRIPT), url, stage, ",".join(keys), str(seconds),
                               *(["release"] if release else [])], stdout=subprocess.PIPE, text=True)
    assert helper.stdout is not None
    assert helper.stdout.readline().strip() == ",".join(keys)
    return helper


def test_a_dead_holders_claims_are_taken_over_at_once(any_db_url: str) -> None:
    """kill -9 of a worker: its claims (900 s lease) are free for the next claimer on its host at once."""
    migrate.upgrade(any_db_url)
    helper = hold_in_helper(any_db_url, "stage", ["a", "b"], seconds=60)
    try:
        assert _claim(any_db_url, ["a", "b", "c"], "w2") == ["c"]  # a live holder keeps its items
    finally:
        helper.kill()
        helper.wait()
    assert _claim(any_db_url, ["a", "b"], "w2") == ["a", "b"]
    assert _claim(any_db_url, ["a", "b"], "w3") == []  # taken over once, by one claimer


def test_a_holder_is_dead_when_its_pid_is_gone_or_reused() -> None:
    me = holder.this_process()
    assert me.started and not holder.is_dead(me.host, me.pid, me.started)
    assert holder.is_dead(me.host, me.pid, str(int(me.started) + 1))  # same pid, another process
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    assert holder.is_dead(me.host, int(gone.stdout), "1")
    assert not holder.is_dead("another-host", int(gone.stdout), "1")  # nothing provable elsewhere


def test_the_heartbeat_renews_a_short_lease_until_it_stops(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    assert _claim(any_db_url, ["a"], claims.worker_id(), lease=1) == ["a"]
    with Heartbeat(any_db_url, lease_seconds=1) as heartbeat:
        time.sleep(2.5)  # a batch longer than the lease
        assert _claim(any_db_url, ["a"], "w2", lease=1) == []
    assert heartbeat.beats >= 5
    time.sleep(1.1)  # no heartbeat any more: the lease runs out
    assert _claim(any_db_url, ["a"], "w2") == ["a"]


def test_holds_list_holders_and_release_frees_only_stale_claims(any_db_url: str) -> None:
    migrate.upgrade(any_db_url)
    _claim(any_db_url, ["live"], "w-live")
    _claim(any_db_url, ["old"], "w-old", lease=0.01)
    helper = hold_in_helper(any_db_url, "stage", ["dead"], seconds=60)
    helper.kill()
    helper.wait()
    engine = make_engine(any_db_url)
    with Session(engine) as session, session.begin():
        held = {h.worker: h for h in claims.holds(session, "stage")}
        assert held["w-live"].count == 1 and not held["w-live"].stale
        assert held["w-old"].expired and not held["w-old"].dead
        dead = next(h for w, h in held.items() if w not in ("w-live", "w-old"))
        assert dead.dead and "claim test helper" in dead.describe()
        assert claims.release_held(session, "stage") == 2
    with Session(engine) as session, session.begin():
        assert [h.worker for h in claims.holds(session)] == ["w-live"]
        assert claims.release_held(session, stale_only=False) == 1
    engine.dispose()
