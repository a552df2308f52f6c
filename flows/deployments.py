"""Deployments from prefect.yaml, served by `photoshape serve` (one declaration, two ways to run it)."""

from __future__ import annotations

import datetime as dt
import importlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from photoshape_flow.config import get_settings
from photoshape_flow.stages import REGISTRY


def prefect_yaml_path() -> Path:
    """prefect.yaml of the checkout, or the copy shipped inside the package."""
    here = Path(__file__).resolve()
    for candidate in (here.parents[1] / "prefect.yaml", here.parent / "prefect.yaml"):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError("prefect.yaml not found next to the flows")


# prefect.yaml's stage deployments are written from the stage registry between these two lines
GENERATED_BEGIN = "  # >>> stage deployments: generated from the stage registry by `photoshape serve --write-yaml`"
GENERATED_END = "  # <<< end of the generated stage deployments"


def stage_deployments_yaml() -> str:
    """The YAML of one deployment per registered stage (flow, description and exclusivity from the registry)."""
    lines = [GENERATED_BEGIN]
    for stage in REGISTRY:
        lines += [
            f"  - name: {stage.name}",
            f"    entrypoint: photoshape_flow.flows.stages.{stage.name.replace('-', '_')}",
            f"    description: {json.dumps(stage.description)}",
            "    tags: [photoshape, stage]",
            "    parameters: {}  # profile: the one the collection was last run with",
            *(["    concurrency_limit: *single"] if stage.exclusive else []),
            "    work_pool: *pool",
            "",
        ]
    return "\n".join([*lines, GENERATED_END]) + "\n"


def write_stage_deployments(path: Path | None = None) -> bool:
    """Rewrite the generated block of prefect.yaml; returns whether the file changed."""
    path = path or prefect_yaml_path()
    text = path.read_text()
    start, end = text.index(GENERATED_BEGIN), text.index(GENERATED_END) + len(GENERATED_END) + 1
    updated = text[:start] + stage_deployments_yaml() + text[end:]
    if updated != text:
        path.write_text(updated)
    return updated != text


def load_declarations(path: Path | None = None) -> list[dict[str, Any]]:
    data = yaml.safe_load((path or prefect_yaml_path()).read_text())
    return list(data.get("deployments") or [])


def load_flow(entrypoint: str) -> Any:
    """`package.module.flow_name` (Prefect's module-path entrypoint) -> the flow object."""
    module_name, _, attr = entrypoint.replace(":", ".").rpartition(".")
    return getattr(importlib.import_module(module_name), attr)


def _trigger(spec: dict[str, Any]) -> Any:
    from prefect.events.schemas.deployment_triggers import DeploymentEventTrigger

    spec = dict(spec)
    spec.pop("type", None)
    for key in ("within", "schedule_after"):
        if isinstance(spec.get(key), int | float):
            spec[key] = dt.timedelta(seconds=spec[key])
    return DeploymentEventTrigger(**spec)


def _schedule(spec: dict[str, Any]) -> Any:
    """A prefect.yaml schedule: `cron:` (with `timezone:`) or `interval:` in seconds (with `anchor_date:`)."""
    from prefect.schedules import Cron, Interval

    active = spec.get("active", True)
    if "interval" in spec:
        anchor = spec.get("anchor_date")
        if isinstance(anchor, str):
            anchor = dt.datetime.fromisoformat(anchor)
        return Interval(spec["interval"], anchor_date=anchor, timezone=spec.get("timezone"), active=active)
    return Cron(spec["cron"], timezone=spec.get("timezone", "UTC"), active=active)


def build_deployments(path: Path | None = None, names: Sequence[str] | None = None) -> list[Any]:
    """RunnerDeployments for every deployment in prefect.yaml (or those in `names`)."""
    from prefect.client.schemas.objects import ConcurrencyLimitConfig, ConcurrencyLimitStrategy
    from prefect.deployments.runner import EntrypointType

    out = []
    for spec in load_declarations(path):
        if names and spec["name"] not in names:
            continue
        limit = spec.get("concurrency_limit")
        concurrency = None
        if limit:
            concurrency = ConcurrencyLimitConfig(
                limit=limit["limit"],
                collision_strategy=ConcurrencyLimitStrategy(limit.get("collision_strategy", "ENQUEUE")),
            )
        flow = load_flow(spec["entrypoint"])
        out.append(flow.to_deployment(
            name=spec["name"],
            description=spec.get("description") or flow.description,
            tags=spec.get("tags"),
            parameters=spec.get("parameters") or {},
            schedules=[_schedule(s) for s in spec.get("schedules") or []] or None,
            triggers=[_trigger(t) for t in spec.get("triggers") or []] or None,
            concurrency_limit=concurrency,
            entrypoint_type=EntrypointType.MODULE_PATH,
        ))
    return out


def serve(names: Sequence[str] | None = None, limit: int | None = None, path: Path | None = None,
          keep_schedules: bool = False) -> None:
    """Serve the deployments of prefect.yaml (or of `path`) in this process until interrupted (runs execute
    in subprocesses). Their schedules are turned into flow runs by the Prefect server's scheduler.

    Stopping (Ctrl-C, SIGTERM) pauses every deployment served, `nightly` included (Prefect's
    `pause_on_shutdown`), until the next `serve` un-pauses them; `keep_schedules` leaves them as they
    were, so the server keeps scheduling runs that wait for the next serving process."""
    from prefect import serve as prefect_serve

    if not get_settings().effective_prefect_api_url:
        raise RuntimeError("no Prefect API: start `prefect server start` and set PREFECT_API_URL")
    prefect_serve(*build_deployments(path, names=names), limit=limit, pause_on_shutdown=not keep_schedules)
