"""The stage registry is the one place stages are declared; everything that runs stages reads it."""

from __future__ import annotations

import ast
import datetime as dt
from pathlib import Path

import pytest
import sqlalchemy as sa
import yaml
from tests.conftest import REPO_ROOT
from typer.testing import CliRunner

from photoshape_flow.stages import REGISTRY, STAGE_NAMES, STAGES, Blocked, StageContext, StageReport, WorkUnit

PIPELINE_ORDER = ("ingest", "coarse-alignment", "fine-alignment", "substances", "training-renders", "training",
                  "inference", "fit", "publish")


def test_registry_lists_every_stage_once_in_pipeline_order() -> None:
    assert STAGE_NAMES == PIPELINE_ORDER
    for stage in REGISTRY:
        assert callable(stage.run) and callable(stage.progress) and stage.writes and stage.description
        assert stage.fans_out == hasattr(stage.entry, "plan") == (stage.plan is not None)
        assert stage.entry.__name__ == f"photoshape_flow.{stage.module}" and stage.module.endswith("_stage")
    assert {s.name for s in REGISTRY if s.fans_out} == {"coarse-alignment", "fine-alignment", "substances",
                                                        "training-renders", "inference", "fit", "publish"}


def test_every_stage_has_a_flow_and_a_deployment_from_the_registry() -> None:
    from photoshape_flow.flows.deployments import load_flow
    from photoshape_flow.flows.stages import STAGE_FLOWS

    declared = yaml.safe_load((REPO_ROOT / "prefect.yaml").read_text())["deployments"]
    entrypoints = {d["entrypoint"] for d in declared}
    for stage in REGISTRY:
        entrypoint = f"photoshape_flow.flows.stages.{stage.name.replace('-', '_')}"
        assert entrypoint in entrypoints, stage.name
        flow = load_flow(entrypoint)
        assert flow is STAGE_FLOWS[stage.name] and flow.name == stage.name
        assert flow.description == stage.description


def _stage_name_tables(path: Path) -> list[int]:
    """Lines of dict literals keyed by three or more stage names (a hand-written dispatch table)."""
    hits = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Dict):
            keys = {k.value for k in node.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)}
            if len(keys & set(PIPELINE_ORDER)) >= 3:
                hits.append(node.lineno)
    return hits


def test_no_other_table_maps_stage_names_to_code() -> None:
    found = {str(p.relative_to(REPO_ROOT)): lines for folder in ("src", "flows")
             for p in (REPO_ROOT / folder).rglob("*.py") if (lines := _stage_name_tables(p))}
    assert found == {}


def test_batches_details_add_counts_and_seconds_and_keep_the_latest_settings() -> None:
    """A run fanned out in batches reports its totals: counts and each phase's seconds add, lists join,
    a setting or a rate (not a count) is the later batch's."""
    a = StageReport("fit", details={"fit:2": {"pairs": 3, "seconds": {"selection": 1.5}, "failed": [[1, "x"]],
                                              "weights": {"color": 0.3, "cases": 40}, "ok": True}})
    b = StageReport("fit", details={"fit:2": {"pairs": 2, "seconds": {"selection": 1.0, "lighting": 2.0},
                                              "failed": [], "weights": {"color": 0.5, "cases": 40}, "ok": True},
                                    "other": 1})
    merged = a.merge(b).details
    publish = StageReport("publish", details={"publish": {"rendered": 2, "render_seconds": 1.5, "method": "fit"}})
    assert publish.merge(publish).details["publish"] == {"rendered": 4, "render_seconds": 3.0, "method": "fit"}
    assert merged["fit:2"]["pairs"] == 5 and merged["fit:2"]["seconds"] == {"selection": 2.5, "lighting": 2.0}
    assert merged["fit:2"]["failed"] == [[1, "x"]] and merged["fit:2"]["ok"] is True and merged["other"] == 1
    assert merged["fit:2"]["weights"] == {"color": 0.5, "cases": 40}  # a setting: the later batch's


def test_reports_merge_counts_holders_and_the_latest_expiry() -> None:
    early, late = dt.datetime(2026, 1, 1, tzinfo=dt.UTC), dt.datetime(2026, 1, 2, tzinfo=dt.UTC)
    a = StageReport("publish", done=2, skipped=1, blocked=Blocked(1, ("w1",), early), seconds=1.5, details={"a": 1})
    b = StageReport("publish", done=1, failed=2, rejected=1, blocked=Blocked(2, ("w2", "w1"), late), seconds=2.0,
                    details={"b": 2})
    merged = a.merge(b)
    assert (merged.done, merged.skipped, merged.failed, merged.rejected, merged.seconds) == (3, 1, 2, 1, 3.5)
    assert merged.blocked == Blocked(3, ("w1", "w2"), late) and merged.details == {"a": 1, "b": 2}
    assert merged.to_dict()["blocked"]["until"] == late.isoformat()


def test_process_claims_each_item_once_and_reopens_failed_items(db_url: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fan-out path: a second worker skips claimed items; a crashed batch is claimable again."""
    from photoshape_flow.stages import process

    seen: list[tuple[int, ...]] = []
    crash = {"on": False}

    def fake_run(ctx: StageContext, cfg: object, work: WorkUnit | None = None) -> StageReport:
        assert work is not None
        if crash["on"]:
            raise RuntimeError("renderer died")
        seen.append(work.ids)
        return StageReport("fine-alignment", done=len(work.ids))

    monkeypatch.setattr(STAGES["fine-alignment"].entry, "run", fake_run)
    ctx = StageContext.create()
    first = process("fine-alignment", WorkUnit("pairs", (1, 2, 3)), "tiny", ctx)
    again = process("fine-alignment", WorkUnit("pairs", (2, 3, 4)), "tiny", ctx)
    assert seen == [(1, 2, 3), (4,)] and (first.done, again.done, again.skipped) == (3, 1, 2)
    crash["on"] = True
    with pytest.raises(RuntimeError):
        process("fine-alignment", WorkUnit("pairs", (5, 6)), "tiny", ctx)
    crash["on"] = False
    retried = process("fine-alignment", WorkUnit("pairs", (5, 6)), "tiny", ctx)
    assert retried.done == 2 and seen[-1] == (5, 6)
    # a changed stage config re-opens the items under a new claim hash
    fresh = process("fine-alignment", WorkUnit("pairs", (1,)), "small", ctx)
    assert fresh.done == 1


def test_cli_run_records_the_resolved_profile_and_reports(db_url: str) -> None:
    from photoshape_flow.cli import app
    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import session_scope
    from photoshape_flow.stages import last_run_profile

    runner = CliRunner()
    shown = runner.invoke(app, ["run", "training", "-p", "medium", "--set", "training.epochs=20", "--show-profile"])
    assert shown.exit_code == 0 and "training.epochs = 20" in shown.output and "publish." not in shown.output
    bad = runner.invoke(app, ["run", "ingest", "--profile", "tiny", "--set", "training.epoch=3"])
    assert bad.exit_code == 1 and "no field 'epoch'" in bad.output
    result = runner.invoke(app, ["run", "ingest", "--profile", "tiny", "--set", "training.epochs=3"])
    assert result.exit_code == 0, result.output
    assert "ingest" in result.output and "{" not in result.output  # a table, never JSON in a cell
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.PipelineRun)).scalar_one()
        assert (row.origin, row.profile_name, row.status) == ("cli", "tiny", "ok")
        assert row.overrides == {"training.epochs": "3"} and row.profile["training"]["epochs"] == 3
        assert row.stages == ["ingest"] and row.reports["ingest"]["done"] == 0
        resolved = last_run_profile(session)
    assert resolved is not None and resolved.profile.training.epochs == 3


def test_prefect_yaml_stage_deployments_are_the_generated_ones() -> None:
    """Edit the registry, then `photoshape serve --write-yaml`; this fails until the file is regenerated."""
    from photoshape_flow.flows.deployments import stage_deployments_yaml

    assert stage_deployments_yaml() in (REPO_ROOT / "prefect.yaml").read_text()
    declared = {d["name"]: d for d in yaml.safe_load((REPO_ROOT / "prefect.yaml").read_text())["deployments"]}
    for stage in REGISTRY:
        assert declared[stage.name]["description"] == stage.description
        assert ("concurrency_limit" in declared[stage.name]) == stage.exclusive
