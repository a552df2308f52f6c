"""The record of running the pipeline: evaluations against ground truth, people's grades, the
shared work ledger and each run's resolved profile."""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column

from photoshape_flow.db.base import (
    Base,
    ParamsHashMixin,
    Short,
    Str,
    TimestampMixin,
    fk,
    utcnow,
)


class Evaluation(Base):
    """One metric of one run against ground truth, comparable across runs in SQL."""

    __tablename__ = "evaluation"
    __table_args__ = (sa.UniqueConstraint("run", "stage", "method", "metric"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    run: Mapped[str] = mapped_column(sa.String(64))
    stage: Mapped[str] = mapped_column(sa.String(32))
    method: Mapped[str] = mapped_column(sa.String(64), default="", server_default="")
    metric: Mapped[str] = mapped_column(sa.String(64))
    value: Mapped[float | None]
    count: Mapped[int | None]
    ci_low: Mapped[float | None] = mapped_column(comment="lower end of the 95% bootstrap interval over exemplars")
    ci_high: Mapped[float | None] = mapped_column(comment="upper end of the 95% bootstrap interval over exemplars")
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)
    groundtruth_sha256: Mapped[str | None] = mapped_column(
        sa.String(64), index=True, comment="sha256 of the ground-truth file scored against (groundtruth_file)")
    created_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())


class GroundTruthFileRow(Base):
    """A ground-truth file `photoshape eval` scored against; the newest used is the default next time.

    Keyed by the file's absolute path: an edited file keeps its row and gets its new sha256, while
    the evaluation rows keep the hash they were computed with.
    """

    __tablename__ = "groundtruth_file"

    id: Mapped[int] = mapped_column(primary_key=True)
    path: Mapped[str] = mapped_column(sa.String(1024), unique=True)
    sha256: Mapped[str] = mapped_column(sa.String(64), index=True)
    version: Mapped[int]
    entries: Mapped[int] = mapped_column(default=0, comment="entries matched to ingested exemplars")
    skipped: Mapped[int] = mapped_column(default=0, comment="entries left out (bad or unknown names)")
    registered_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())
    used_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now(), index=True)


class Grade(TimestampMixin, Base):
    """A person's verdict on a PhotoShape, from the original code's result taxonomy.

    Keyed by what was graded, not by the pair alone: the method key and the assignment-set key
    (`publish.photoshapes.assignment_set_keys`) of the rank-1 materials the PhotoShape showed, so
    a new classifier's (or a re-ranked) PhotoShape of the same pair starts ungraded while the old
    grade stays. NULL keys: a grade from before they were recorded whose PhotoShape is unknown.
    """

    __tablename__ = "grade"
    __table_args__ = (sa.UniqueConstraint("pair_id", "method_key", "assignment_set", "grader"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(fk("pair.id"), index=True)
    method_key: Mapped[str | None] = mapped_column(sa.String(64), comment="the graded PhotoShape's method key")
    assignment_set: Mapped[str | None] = mapped_column(
        sa.String(64), comment="key of the rank-1 assignment set it showed; NULL: legacy grade")
    label: Mapped[str] = mapped_column(Short)
    note: Mapped[str | None] = mapped_column(sa.Text)
    grader: Mapped[str] = mapped_column(sa.String(64), default="user", server_default="user")


class WorkClaim(TimestampMixin, ParamsHashMixin, Base):
    """Ledger of per-item stage work shared by several workers: claimed (with a lease), done or failed.

    A claim whose lease has expired, or whose holder is provably dead (same host, process gone or
    its pid reused: `db.holder`), may be taken by another worker, so a killed worker's items are
    picked up again; `done` rows make re-runs skip finished items. Live holders renew their lease.
    """

    __tablename__ = "work_claim"
    __table_args__ = (sa.UniqueConstraint("stage", "item_key"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    stage: Mapped[str] = mapped_column(sa.String(32))
    item_key: Mapped[str] = mapped_column(Str)
    state: Mapped[str] = mapped_column(Short, default="claimed", comment="claimed | done | failed")
    worker: Mapped[str | None] = mapped_column(sa.String(128))
    lease_expires_at: Mapped[dt.datetime | None]
    attempts: Mapped[int] = mapped_column(default=0)
    error: Mapped[str | None] = mapped_column(sa.Text)
    holder_host: Mapped[str | None] = mapped_column(sa.String(128), comment="host name of the claiming process")
    holder_pid: Mapped[int | None] = mapped_column(comment="its process id")
    holder_started: Mapped[str | None] = mapped_column(
        sa.String(32), comment="its start time (clock ticks since boot): a reused pid differs")
    holder_name: Mapped[str | None] = mapped_column(sa.String(128), comment="worker name, e.g. photoshape run")


class PipelineRun(Base):
    """One `photoshape run` / `demo` / flow run: the resolved profile it used and what each stage did.

    The newest row tells later runs (the material-added re-run, deployments) which profile the
    collection was built with; `profile` holds every resolved value, `overrides` what was asked for.
    """

    __tablename__ = "pipeline_run"

    id: Mapped[int] = mapped_column(primary_key=True)
    origin: Mapped[str] = mapped_column(sa.String(32), comment="cli | demo | flow")
    profile_name: Mapped[str] = mapped_column(sa.String(64), index=True)
    overrides: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="path -> value as given (--set)")
    profile: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="every resolved profile value")
    stages: Mapped[list[Any]] = mapped_column(default=list, comment="stage names asked for, in order")
    reports: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="stage -> StageReport as JSON")
    status: Mapped[str] = mapped_column(Short, default="running", comment="running | ok | failed")
    error: Mapped[str | None] = mapped_column(sa.Text)
    started_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())
    finished_at: Mapped[dt.datetime | None]
    holder_host: Mapped[str | None] = mapped_column(sa.String(128), comment="host name of the running process")
    holder_pid: Mapped[int | None] = mapped_column(comment="its process id")
    holder_started: Mapped[str | None] = mapped_column(
        sa.String(32), comment="its start time (clock ticks since boot): a reused pid differs")
