"""Deployments are declared once in prefect.yaml; the package ships flows, migrations and that file."""

from __future__ import annotations

import datetime as dt
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml
from photoshape_flow.flows.deployments import build_deployments, load_declarations
from tests.conftest import REPO_ROOT
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.stages import STAGE_NAMES as STAGES


def test_every_declared_deployment_is_built_and_listed() -> None:
    declared = [d["name"] for d in load_declarations(REPO_ROOT / "prefect.yaml")]
    built = [d.name for d in build_deployments()]
    assert built == declared
    listed = CliRunner().invoke(app, ["serve", "--list"]).output.split()
    assert [w for w in listed if w in declared] == declared


def test_one_deployment_per_stage_plus_pipeline_and_new_materials() -> None:
    names = {d["name"] for d in load_declarations()}
    assert set(STAGES) <= names
    assert {"nightly", "new-materials"} <= names
    flows = {d.name: d for d in build_deployments()}
    for stage in STAGES:
        assert flows[stage].flow_name == stage  # flows are named by the canonical stage list


def test_nightly_schedule_and_debounced_material_trigger() -> None:
    deployments = {d.name: d for d in build_deployments()}
    nightly = deployments["nightly"]
    assert nightly.schedules and nightly.schedules[0].schedule.cron == "0 2 * * *"
    assert nightly.concurrency_limit == 1
    new = deployments["new-materials"]
    (trigger,) = new.triggers
    assert trigger.expect == {"photoshape.material.added"}
    assert trigger.posture == "Reactive" and trigger.threshold == 1
    assert trigger.within >= dt.timedelta(minutes=5) and trigger.schedule_after > dt.timedelta(0)
    assert new.concurrency_limit == 1
    assert new.concurrency_options.collision_strategy == "CANCEL_NEW"


def test_interval_schedules_are_read_from_the_declarations(tmp_path: Path) -> None:
    (publish,) = [d for d in load_declarations() if d["name"] == "publish"]
    schedules = [{"interval": 90, "anchor_date": "2026-01-01T00:00:00+00:00"}, {"cron": "0 3 * * *"}]
    declarations = tmp_path / "prefect.yaml"
    declarations.write_text(yaml.safe_dump({"deployments": [{**publish, "schedules": schedules}]}))
    (deployment,) = build_deployments(declarations)
    interval, cron = (s.schedule for s in deployment.schedules)
    assert interval.interval == dt.timedelta(seconds=90)
    assert interval.anchor_date == dt.datetime(2026, 1, 1, tzinfo=dt.UTC)
    assert cron.cron == "0 3 * * *" and cron.timezone == "UTC"


def test_flow_parameters_are_typed_for_ui_forms() -> None:
    """Every deployment has a description and only typed, defaulted parameters, so the UI's "Quick run"
    starts it; an empty profile means the one the collection was last run with."""
    from photoshape_flow.flows.deployments import load_flow
    from prefect.utilities.callables import parameter_schema

    with_profile = 0
    for spec in load_declarations():
        flow = load_flow(spec["entrypoint"])
        assert (spec.get("description") or flow.description), spec["name"]
        schema = parameter_schema(flow.fn).model_dump()
        assert not schema.get("required"), (spec["name"], schema.get("required"))
        assert all("type" in p or "anyOf" in p or "enum" in p for p in schema["properties"].values()), spec["name"]
        if "profile" in schema["properties"]:
            with_profile += 1
            choice = schema["properties"]["profile"]
            assert choice["default"] is None and "profile" not in (spec.get("parameters") or {}), spec["name"]
            assert [c.get("enum") for c in choice["anyOf"]][0] == ["tiny", "small", "medium", "default", "paper"]
    assert with_profile >= len(STAGES) + 2


def test_every_deployment_quick_runs_without_parameters() -> None:
    """Prefect's "Quick run" sends only the declared parameters: a flow parameter without a default
    that the declaration does not fill fails the run before it starts (the evaluate deployment did)."""
    from photoshape_flow.flows.deployments import load_flow
    from prefect.utilities.callables import parameter_schema

    for spec in load_declarations():
        schema = parameter_schema(load_flow(spec["entrypoint"]).fn).model_dump()
        unfilled = set(schema.get("required") or ()) - set(spec.get("parameters") or {})
        assert not unfilled, (spec["name"], unfilled)


@pytest.mark.slow
def test_installed_wheel_carries_flows_migrations_and_prefect_yaml(tmp_path: Path) -> None:
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path), str(REPO_ROOT)], check=True)
    (wheel,) = tmp_path.glob("photoshape_flow-*.whl")
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    assert yaml.safe_load((site / "photoshape_flow/flows/prefect.yaml").read_text())["deployments"]
    assert list((site / "photoshape_flow/migrations/versions").glob("*.py"))
    # Import from the unpacked wheel, from a folder that is not the checkout.
    # every package of the source tree must be in the wheel: the editable install of the test's own
    # interpreter would otherwise fill in a missing subpackage from the checkout and hide it
    packages = sorted({".".join(p.relative_to(REPO_ROOT / "src").parent.parts)
                       for p in (REPO_ROOT / "src" / "photoshape_flow").rglob("__init__.py")})
    missing = [name for name in packages if not (site / name.replace(".", "/") / "__init__.py").is_file()]
    assert missing == [], f"packages missing from the wheel (pyproject.toml packages): {missing}"
    code = (
        "import photoshape_flow.flows.pipeline as p, photoshape_flow.db.migrate as mg;"
        "from photoshape_flow.flows.deployments import build_deployments;"
        "print(p.__file__); print(len(build_deployments()));"
        f"mg.upgrade('sqlite:///{tmp_path}/w.db'); print(mg.current_revision('sqlite:///{tmp_path}/w.db'))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                         env={"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)})
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.split()
    assert lines[0].startswith(str(site))
    assert int(lines[1]) == len(load_declarations())
    assert lines[2] not in ("None", "")
