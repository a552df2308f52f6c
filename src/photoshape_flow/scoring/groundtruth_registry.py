"""Which ground-truth file `photoshape eval` and the `evaluate` deployment score against by default.

Every evaluation registers its file (table `groundtruth_file`, keyed by absolute path, with the
sha256 it had); the default is the most recently used registered file that still exists, else the
newest demo's groundtruth.json under the data root, so a fresh demo evaluates with no argument.
"""

from __future__ import annotations

from pathlib import Path

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.base import utcnow
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.demo import newest_groundtruth
from photoshape_flow.evaluation.groundtruth import GroundTruthFile

NO_GROUNDTRUTH = ("no ground truth given, none registered and no demo under the data root: pass one "
                  "(--groundtruth FILE, format in docs/evaluation.md) or run `photoshape demo`")


def register_groundtruth(session: Session, gt: GroundTruthFile, matched: int, skipped: int) -> None:
    """Record (or refresh) the file as the latest used, with its hash and how many entries counted."""
    upsert(session, m.GroundTruthFileRow, {
        "path": str(Path(gt.path).resolve()), "sha256": gt.sha256, "version": gt.version,
        "entries": matched, "skipped": skipped, "used_at": utcnow(),
    }, key=["path"])


def registered_groundtruth(session: Session) -> Path | None:
    """The most recently used registered file that is still on disk (None when there is none)."""
    rows = session.execute(
        sa.select(m.GroundTruthFileRow.path).order_by(m.GroundTruthFileRow.used_at.desc(),
                                                      m.GroundTruthFileRow.id.desc())
    ).scalars()
    return next((Path(p) for p in rows if Path(p).is_file()), None)


def default_groundtruth(session: Session, data_root: Path) -> Path | None:
    """The registered file, else the newest demo's ground truth (None: nothing to score against)."""
    return registered_groundtruth(session) or newest_groundtruth(data_root)


def resolve_groundtruth(given: str | Path | None, settings: Settings | None = None) -> tuple[Path, bool]:
    """The file to score against and whether it was a default (`eval` without a file, the deployment's
    Quick run); raises ValueError with NO_GROUNDTRUTH when there is none."""
    if given is not None:
        return Path(given), False
    settings = settings or get_settings()
    with session_scope(settings.resolved_database_url) as session:
        found = default_groundtruth(session, settings.data_root)
    if found is None:
        raise ValueError(NO_GROUNDTRUTH)
    return found, True
