"""What the `pipeline_run` table says about past runs (the stages record them; readers live here).

The newest run's resolved profile is what the collection was last built with: `photoshape status`
counts pending work by it, and re-runs can default to it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow
from photoshape_flow.db.holder import is_dead
from photoshape_flow.profiles import DEFAULT_PUBLISH_METHOD, ResolvedProfile, resolve_profile

DIED = "died"  # the status of a run whose process ended without recording its end


def mark_dead_runs(session: Session) -> list[int]:
    """Mark `died` every `running` run whose process is provably gone; returns their ids.

    A run killed (SIGKILL, out of memory, a lost machine) never reaches `finish_run`, so its row
    said `running` forever and `photoshape status` counted it. Each run records its process like a
    work claim does, and `db.holder.is_dead` (same host, pid gone or reused) decides; a run on
    another host, or recorded before holders were, is left as it is: nothing there is provable.
    Called by `status` and by every new run, so neither shows a dead run as running.
    """
    rows = session.execute(sa.select(m.PipelineRun).where(m.PipelineRun.status == "running",
                                                          m.PipelineRun.holder_pid.is_not(None))).scalars().all()
    dead = [row for row in rows if is_dead(row.holder_host, row.holder_pid, row.holder_started)]
    for row in dead:
        row.status, row.finished_at = DIED, utcnow()
        row.error = (f"its process ({row.holder_host}:{row.holder_pid}) ended without finishing the run "
                     "(killed, or out of memory)")
    session.flush()
    settle_orphan_training(session)
    return [row.id for row in dead]


def settle_orphan_training(session: Session) -> int:
    """Mark `failed` every classifier still `training` while no run is running; returns how many.

    Training happens inside a run, and a run that ends (ok, failed, interrupted) marks its classifier
    ok or failed; only a process killed outright (SIGKILL, out of memory) leaves a row `training`, which
    `status` and the Prefect summary then reported as pending after every later successful run. With
    no run left running nobody is training it. The row keeps its checkpoint: the next run with the
    same inputs resumes from it, as from any failed row.
    """
    if session.execute(sa.select(m.PipelineRun.id).where(m.PipelineRun.status == "running").limit(1)).first():
        return 0
    result = session.execute(
        sa.update(m.Classifier).where(m.Classifier.status == "training")
        .values(status="failed", updated_at=utcnow(),
                error="interrupted: its run ended without finishing it (the next run resumes from its checkpoint)"))
    return int(getattr(result, "rowcount", 0) or 0)


def last_run(session: Session) -> m.PipelineRun | None:
    return session.execute(sa.select(m.PipelineRun).order_by(m.PipelineRun.id.desc()).limit(1)).scalar_one_or_none()


def run_profile(row: m.PipelineRun) -> ResolvedProfile:
    """The resolved profile a recorded run used: its profile name with its overrides re-applied."""
    return resolve_profile(row.profile_name, dict(row.overrides or {}))


def last_run_profile(session: Session) -> ResolvedProfile | None:
    """The profile of the newest recorded run, with its overrides (None before the first run)."""
    row = last_run(session)
    return None if row is None else run_profile(row)


def published_method(session: Session) -> str:
    """The method the collection publishes with: its last run's `publish.method` (the default before any run).

    The gallery, export and grade commands show this when no `--method` is given, so they show what
    `photoshape run publish` rendered, also for a collection built with `--set publish.method=classifier`.
    """
    row = last_run(session)  # its recorded, resolved profile: no re-resolution that a renamed profile could fail
    recorded = ((row.profile if row is not None else None) or {}).get("publish") or {}
    return str(recorded.get("method") or DEFAULT_PUBLISH_METHOD)


def effective_profile(session: Session, name: str | None, overrides: Sequence[str] = ()) -> tuple[str, list[str]]:
    """The (profile name, overrides) a run asked for, as `--set` strings.

    `name=None` means "the profile the collection was last run with" (with that run's overrides, the
    given ones applied on top), or `default` before the first run: deployments default to it, so a
    schedule or the material-added trigger never resizes a collection to a fixed preset.
    """
    if name is not None:
        return name, list(overrides)
    row = last_run(session)
    if row is None:
        return "default", list(overrides)
    recorded = [f"{path}={value if isinstance(value, str) else json.dumps(value)}"
                for path, value in (row.overrides or {}).items()]
    given = {text.partition("=")[0].strip() for text in overrides}
    return row.profile_name, [t for t in recorded if t.partition("=")[0] not in given] + list(overrides)
