"""Stages run through the work claims from the CLI as from the flows: blocked items are reported (and make
`photoshape run` exit non-zero unless --wait), leases are renewed while a batch runs, and an item whose
inputs changed (publish: a new classifier's assignment) is claimed again."""

from __future__ import annotations

import datetime as dt
import time

import pytest
import sqlalchemy as sa
from tests.db.claim_holder import HELPER_NAME
from tests.db.seed import seed
from tests.db.test_claims import hold_in_helper
from typer.testing import CliRunner

from photoshape_flow.config import get_settings
from photoshape_flow.db import claims
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.profiles import resolve_profile
from photoshape_flow.stages import STAGES, StageContext, StageReport, WorkUnit, process

runner = CliRunner()


def _fake_stage(monkeypatch: pytest.MonkeyPatch, name: str, seen: list[tuple[int, ...]], pause: float = 0.0,
                during: object = None) -> None:
    """Replace a stage's science (not its claims) with a recorder."""

    def fake_run(ctx: StageContext, cfg: object, work: WorkUnit | None = None) -> StageReport:
        assert work is not None
        time.sleep(pause)
        if callable(during):
            during()
        seen.append(work.ids)
        return StageReport(name, done=len(work.ids))

    monkeypatch.setattr(STAGES[name].entry, "run", fake_run)


def test_items_a_live_worker_holds_are_reported_blocked(db_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[int, ...]] = []
    _fake_stage(monkeypatch, "fine-alignment", seen)
    with session_scope(db_url) as session:
        claims.claim(session, "fine-alignment:pairs", ["1", "2"], worker="other-worker", lease_seconds=900)
    report = process("fine-alignment", WorkUnit("pairs", (1, 2, 3)), "tiny", StageContext.create())
    assert seen == [(3,)] and (report.done, report.skipped, report.blocked.count) == (1, 0, 2)
    assert report.blocked.holders[0].startswith("other-worker (")
    assert report.blocked.until is not None
    assert report.blocked.until > dt.datetime.now(dt.UTC) + dt.timedelta(seconds=800)


def test_a_batch_longer_than_its_lease_keeps_its_claims(db_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Lease 1 s, batch 2.5 s: the heartbeat renews it, so a second worker never wins the items meanwhile."""
    monkeypatch.setenv("PHOTOSHAPE_CLAIM_LEASE_SECONDS", "1")
    get_settings.cache_clear()
    stolen: list[str] = []

    def second_worker() -> None:
        with session_scope(db_url) as session:
            stolen.extend(claims.claim(session, "fine-alignment:pairs", ["1", "2"], worker="w2", lease_seconds=1))

    seen: list[tuple[int, ...]] = []
    _fake_stage(monkeypatch, "fine-alignment", seen, pause=2.5, during=second_worker)
    report = process("fine-alignment", WorkUnit("pairs", (1, 2)), "tiny", StageContext.create())
    assert report.done == 2 and stolen == []
    with session_scope(db_url) as session:
        assert claims.counts(session) == {("fine-alignment:pairs", "done"): 2}


def test_cli_run_exits_non_zero_while_a_live_worker_holds_the_stage_and_waits_with_wait(
        db_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.cli import app
    from photoshape_flow.stages import run as run_module

    monkeypatch.setattr(run_module, "WAIT_POLL_SECONDS", 0.2)
    helper = hold_in_helper(db_url, "ingest", ["stage"], seconds=2.0, release=True)  # a second `run` in progress
    try:
        blocked = runner.invoke(app, ["run", "ingest", "--profile", "tiny"])
        assert blocked.exit_code == 3, blocked.output
        flat = " ".join(blocked.output.split())
        assert "ingest: 1 item held by another live worker" in flat and HELPER_NAME in flat and "until" in flat
        started = time.monotonic()
        waited = runner.invoke(app, ["run", "ingest", "--profile", "tiny", "--wait"])
        assert waited.exit_code == 0, waited.output
        assert time.monotonic() - started > 0.5  # it did wait for the helper to finish
    finally:
        helper.kill()
        helper.wait()
    with session_scope(db_url) as session:
        runs = session.execute(sa.select(m.PipelineRun.status).order_by(m.PipelineRun.id)).scalars().all()
        assert runs == ["blocked", "ok"]
        assert claims.holds(session) == []  # the stage-level claim is released after the run


def test_cli_fan_out_stages_share_the_flows_claims(db_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """`photoshape run fine-alignment` claims through plan + process: a second run finds the pair done."""
    from photoshape_flow.cli import app

    with session_scope(db_url) as session:
        pair = seed(session)["pair"]
    seen: list[tuple[int, ...]] = []
    _fake_stage(monkeypatch, "fine-alignment", seen)
    for _ in range(2):
        result = runner.invoke(app, ["run", "fine-alignment", "--profile", "tiny"])
        assert result.exit_code == 0, result.output
    assert seen == [(pair,)]


def test_publish_claims_a_pair_again_when_a_new_classifier_assigns_it(db_url: str,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    with session_scope(db_url) as session:
        ids = seed(session)
        oak = session.execute(sa.select(m.Material.id).where(m.Material.name == "oak")).scalar_one()
    seen: list[tuple[int, ...]] = []
    _fake_stage(monkeypatch, "publish", seen)
    ctx, unit = StageContext.create(), WorkUnit("pairs", (ids["pair"],))
    shown = resolve_profile("tiny", ["publish.method=classifier"])  # the seeded rows are the classifier's
    assert process("publish", unit, shown, ctx).done == 1
    assert process("publish", unit, shown, ctx).skipped == 1  # published, same assignment
    with session_scope(db_url) as session:  # a retrained classifier's ranking of the same pair
        newer = m.Classifier(name="r34-2", kind="material", architecture="resnet34", materials=[0, oak])
        session.add(newer)
        session.flush()
        parts = session.execute(sa.select(m.Part.id).where(m.Part.shape_id == ids["shape"])).scalars().all()
        session.add_all([m.Assignment(pair_id=ids["pair"], part_id=part, method="classifier", classifier_id=newer.id,
                                      method_key=f"classifier:{newer.id}", rank=1, material_id=oak, score=0.7)
                         for part in parts])
    again = process("publish", unit, shown, ctx)
    assert again.done == 1 and seen == [unit.ids, unit.ids]


def test_a_finishing_step_runs_once_at_a_time(db_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two workers done with publish's batches: only one writes the gallery, the other is told who does."""
    from photoshape_flow.stages import finish

    calls: list[str] = []

    def fake_finish(ctx: StageContext, cfg: object) -> StageReport:
        calls.append("gallery")
        return StageReport("publish")

    monkeypatch.setattr(STAGES["publish"].entry, "finish", fake_finish)
    ctx = StageContext.create()
    with session_scope(db_url) as session:
        claims.claim(session, "publish:finish", ["stage"], worker="other-worker", lease_seconds=900)
    blocked = finish("publish", "tiny", ctx)
    assert blocked is not None and blocked.blocked.count == 1 and calls == []
    with session_scope(db_url) as session:
        claims.release(session, "publish:finish", ["stage"], worker="other-worker")
    assert finish("publish", "tiny", ctx).blocked.count == 0 and calls == ["gallery"]
    with session_scope(db_url) as session:
        assert claims.holds(session) == []  # released after the step
