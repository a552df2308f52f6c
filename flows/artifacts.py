"""UI artifacts of a run: a markdown summary, a table of candidates, progress of long stages."""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable, Sequence
from typing import Any

import sqlalchemy as sa
from prefect.artifacts import (
    create_markdown_artifact,
    create_progress_artifact,
    create_table_artifact,
    update_progress_artifact,
)

from photoshape_flow.config import get_settings
from photoshape_flow.db.session import session_scope
from photoshape_flow.pipeline.progress import assumed_profile, rendering_progress
from photoshape_flow.pipeline.runs import mark_dead_runs
from photoshape_flow.progress_sink import progress_line
from photoshape_flow.publish.gallery_site import write_contact_sheet
from photoshape_flow.stages import stage_progress


def candidate_rows(limit: int = 200, since_pair_ids: Sequence[int] | None = None,
                   method: str = "classifier") -> list[dict[str, Any]]:
    """One row per PhotoShape candidate of `method` (what `publish.method` shows), best first: pair,
    shape and exemplar by name, method key, the gallery's score (mean part confidence over the parts
    seen), the weakest part's confidence, whether it is published, its grade."""
    query = """
        SELECT pair_id, shape_name, exemplar_name, method_key, COUNT(*) AS parts,
               score, MIN(confidence) AS weakest_part, published, grade,
               MIN(hog_distance) AS hog_distance, MIN(alignment_iou) AS alignment_iou
        FROM photoshape_candidate
        WHERE method = :method
        GROUP BY pair_id, shape_name, exemplar_name, method_key, score, published, grade
        ORDER BY score DESC, pair_id
    """
    with session_scope(get_settings().resolved_database_url) as session:
        rows = [dict(r._mapping) for r in session.execute(sa.text(query), {"method": method})]
    if since_pair_ids is not None:
        wanted = set(since_pair_ids)
        rows = [r for r in rows if r["pair_id"] in wanted]
    for r in rows:
        r["published"] = bool(r["published"])
        for key in ("score", "weakest_part", "hog_distance", "alignment_iou"):
            if r[key] is not None:
                r[key] = round(float(r[key]), 4)
    return rows[:limit]


def publish_candidates_table(key: str = "photoshape-candidates", rows: list[dict[str, Any]] | None = None,
                             method: str = "classifier") -> None:
    rows = candidate_rows(method=method) if rows is None else rows
    if rows:
        create_table_artifact(table=rows, key=key, description=f"PhotoShape candidates of {method}, best first")


def publish_summary(title: str, stage_times: dict[str, float], extra: dict[str, Any] | None = None,
                    key: str = "photoshape-run-summary", changes: dict[str, int] | None = None) -> None:
    """Markdown: per-stage wall time and the done/pending/failed/rejected counts of every stage, and
    (`changes`, a `FitChanges` as a dict) how many parts the run's fit changed."""
    with session_scope(get_settings().resolved_database_url) as session:
        mark_dead_runs(session)  # the summary's counts never include a killed run as running
        progress = stage_progress(session)
        renderings = rendering_progress(session)
        assumed = assumed_profile(session)
    lines = [f"# {title}", "", f"Counts assume {assumed.describe()}.", "",
             "| stage | seconds | unit | done | pending | failed | rejected |", "|---|---:|---|---:|---:|---:|---:|"]
    for p in progress:
        seconds = stage_times.get(p.stage)
        shown = f"{seconds:.1f}" if seconds is not None else ""
        lines.append(f"| {p.stage} | {shown} | {p.unit} | {p.done} | {p.pending} | {p.failed} | {p.rejected} |")
    if renderings:
        lines += ["", "| rendering | made by | ok | failed | rejected | why rejected |", "|---|---|---:|---:|---:|---|"]
        lines += [f"| {r.kind} | {r.stage} | {r.ok} | {r.failed} | {r.rejected} | "
                  f"{r.reasons_text().replace('|', '/')} |" for r in renderings]
    if changes:
        lines += ["", "| fit: parts | candidate set grew | winner changed | won by a new material |",
                  "|---:|---:|---:|---:|",
                  f"| {changes['parts']} | {changes['grown']} | {changes['changed']} | {changes['won_by_new']} |"]
    for name, value in (extra or {}).items():
        lines += ["", f"**{name}**: {value}"]
    create_markdown_artifact(markdown="\n".join(lines), key=key, description=title)


class Progress:
    """A progress artifact updated as batches finish."""

    def __init__(self, stage: str, total: int):
        self.total = max(total, 1)
        self.done = 0
        self.id = create_progress_artifact(progress=0.0, key=f"{stage}-progress",
                                           description=f"{stage}: batches done")

    def step(self) -> None:
        self.done += 1
        update_progress_artifact(self.id, progress=100.0 * self.done / self.total)


class ArtifactProgress:
    """The flows' progress sink (`progress_sink.Progress`): one Prefect progress artifact per loop.

    Its percentage follows the loop and its description carries the same count, rate and ETA line
    the CLI prints off a terminal. Updates are rate-limited to one per `every_seconds` (and the end)
    so a fast loop does not flood the API; artifacts are best effort: a failure is logged once and
    the stage goes on.
    """

    def __init__(self, every_seconds: float = 2.0, clock: Callable[[], float] = time.monotonic):
        self.every_seconds, self.clock = every_seconds, clock
        self.loops: dict[str, tuple[Any, float, float]] = {}  # task -> (artifact id, started, last update)
        self.broken = False

    def __call__(self, task: str, done: int, total: int) -> None:
        if self.broken:
            return
        now = self.clock()
        percent = 100.0 * done / total if total else 0.0
        try:
            if task not in self.loops or done == 0:
                key = re.sub(r"[^a-z0-9]+", "-", task.lower()).strip("-") + "-items"
                artifact = create_progress_artifact(progress=percent, key=key,
                                                    description=progress_line(task, done, total, 0.0))
                self.loops[task] = (artifact, now, now)
                return
            artifact, started, last = self.loops[task]
            if now - last >= self.every_seconds or (total and done >= total):
                update_progress_artifact(artifact, progress=percent,
                                         description=progress_line(task, done, total, now - started))
                self.loops[task] = (artifact, started, now)
        except Exception as exc:  # progress is best effort: the stage's work matters more
            self.broken = True
            logging.getLogger(__name__).warning("progress artifacts off for this task: %s", exc)


def publish_gallery_artifacts(gallery_index: str | None, method: str | None = None) -> dict[str, str]:
    """After publish: the contact sheet of `method`'s candidates as an image artifact and a link to the gallery.

    The sheet is written next to the gallery (`contact-sheet.png`) and shown in the UI as an inline
    JPEG (a data URL: the Prefect UI cannot load files from the data root). Returns the keys made.
    """
    import base64
    from pathlib import Path

    import cv2
    from prefect.artifacts import create_image_artifact, create_link_artifact

    made: dict[str, str] = {}
    if gallery_index:
        index = Path(gallery_index).resolve()
        made["gallery"] = str(create_link_artifact(link=index.as_uri(), link_text=f"PhotoShape gallery ({index})",
                                                   key="photoshape-gallery", description="The published gallery"))
        try:
            sheet = write_contact_sheet(index.parent / "contact-sheet.png", method)
        except ValueError as exc:  # nothing rendered yet: no sheet to show
            made["contact-sheet"] = f"skipped: {exc}"
            return made
        image = cv2.imread(str(sheet))
        scale = min(1.0, 960 / image.shape[1])
        small = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else image
        ok, jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, 80])
        if ok:
            url = "data:image/jpeg;base64," + base64.b64encode(jpeg.tobytes()).decode()
            made["contact-sheet"] = str(create_image_artifact(
                image_url=url, key="photoshape-contact-sheet",
                description=f"Best PhotoShapes: exemplar, built-in, PhotoShape, novel views ({sheet})"))
    return made
