"""Four worker processes running the same stage against PostgreSQL: every item once, none lost."""

from __future__ import annotations

import multiprocessing as mp
import os

import pytest
import sqlalchemy as sa

pytestmark = pytest.mark.postgres


def _worker(url: str, data_root: str, batches: list[list[int]], queue: mp.Queue) -> None:
    os.environ["PHOTOSHAPE_DATABASE_URL"] = url
    os.environ["PHOTOSHAPE_DATA_ROOT"] = data_root
    from photoshape_flow.stages import StageContext, WorkUnit, process

    claimed = []
    for batch in batches:
        report = process("inference", WorkUnit("color-match", tuple(batch)), "tiny", StageContext.create())
        claimed.append(report.done + report.failed)
    queue.put(claimed)


def test_four_workers_share_a_stage_without_doing_an_item_twice(pg_url: str, tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from tests.pipeline.aligned import make_aligned_pairs

    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import get_engine, session_scope
    from photoshape_flow.store import BlobStore

    data_root = tmp_path / "data"
    monkeypatch.setenv("PHOTOSHAPE_DATABASE_URL", pg_url)
    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", str(data_root))
    get_settings.cache_clear()
    get_engine.cache_clear()
    migrate.upgrade(pg_url)
    made = make_aligned_pairs(pg_url, BlobStore(get_settings().blob_root), n_pairs=24)
    pairs = list(made["pairs"])  # type: ignore[arg-type]
    batches = [pairs[i : i + 3] for i in range(0, len(pairs), 3)]
    ctx = mp.get_context("spawn")
    queue: mp.Queue = ctx.Queue()
    # every worker walks all batches (in a different order): only claims keep them apart
    procs = [ctx.Process(target=_worker, args=(pg_url, str(data_root), batches[k:] + batches[:k], queue))
             for k in range(4)]
    for p in procs:
        p.start()
    claimed = [sum(queue.get(timeout=300)) for _ in procs]
    for p in procs:
        p.join(timeout=60)
    assert sum(claimed) == len(pairs)  # each item claimed by exactly one worker
    with session_scope(pg_url) as session:
        attempts = session.execute(
            sa.select(m.WorkClaim.attempts, m.WorkClaim.state).where(m.WorkClaim.stage.like("inference%"))
        ).all()
        per_pair = session.execute(
            sa.select(m.Assignment.pair_id, sa.func.count()).where(m.Assignment.rank == 1)
            .group_by(m.Assignment.pair_id)
        ).all()
    assert len(attempts) == len(pairs) and all(a == 1 and s == "done" for a, s in attempts)
    assert sorted(p for p, _ in per_pair) == sorted(pairs)  # none lost
    assert all(n == 3 for _, n in per_pair)  # one rank-1 row per part, never duplicated
    get_settings.cache_clear()
    get_engine.cache_clear()
