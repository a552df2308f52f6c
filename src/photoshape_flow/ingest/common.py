"""Shared pieces of the four ingest stages: the summary, failure rows, limits, hashing, splits, the material event.

Every ingest stage follows one pattern per item: compute the content hash of the source files,
skip the item when a row with the same natural key, hash and parameters is already `ok`
("present"), otherwise process it, write blobs, then upsert the row in its own transaction
("added" or "replaced"). Bad input becomes a `rejected` row (crashes and timeouts `failed`) with
a one-line error, a summary line and a log line, and the batch goes on.
"""

from __future__ import annotations

import copy
import hashlib
import logging
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db.base import Base
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.export.text import one_line as text_line
from photoshape_flow.geometry.archive import ArchiveLimits
from photoshape_flow.progress_sink import Progress as ProgressSink
from photoshape_flow.store import BlobStore, default_store, sha256_file
from photoshape_flow.vocab import STATUS_OK

logger = logging.getLogger(__name__)
T = TypeVar("T")

# progress(label, done, total) after each item: the one progress interface (progress_sink.py), whose
# task is here the item just handled (the ingest stage re-labels it with its collection)
Progress = ProgressSink


@dataclass
class IngestSummary:
    """What one ingest call did. Ids are row ids of the collection's table."""

    kind: str
    added: list[int] = field(default_factory=list)
    present: list[int] = field(default_factory=list)
    replaced: list[int] = field(default_factory=list)
    rejected: list[tuple[str, str]] = field(default_factory=list)  # (path or label, reason)
    duplicates: list[tuple[int, int]] = field(default_factory=list)  # exemplars: (id, duplicate of id)
    warnings: list[tuple[str, str]] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)  # informational (e.g. previews)
    announced: bool | None = None  # materials: whether the material-added event went out; None: nothing to tell

    @property
    def new_material_ids(self) -> list[int]:
        """Materials added by this call (empty for the other collections)."""
        return list(self.added) if self.kind == "materials" else []

    @property
    def total(self) -> int:
        return len(self.added) + len(self.present) + len(self.replaced) + len(self.rejected)

    def reject(self, label: str, reason: str) -> None:
        """Note a rejected input; label and reason are made one safe line (names may hold anything)."""
        label, reason = text_line(label), text_line(reason)
        self.rejected.append((label, reason))
        logger.warning("%s: %s", label, reason)

    def count_written(self, label: str, row_id: int, existing: Mapping[str, Any] | None, noun: str) -> None:
        """Count a freshly written `ok` row: "replaced" when it overwrote an `ok` row, else "added".

        A row that was rejected or failed before counts as added: only good content is replaced.
        """
        if existing is not None and existing["status"] == STATUS_OK:
            self.replaced.append(row_id)
            logger.info("%s: replaced %s %d (new content)", label, noun, row_id)
        else:
            self.added.append(row_id)

    def warn(self, label: str, message: str) -> None:
        label, message = text_line(label), text_line(message)
        self.warnings.append((label, message))
        logger.info("%s: %s", label, message)

    def as_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "added": self.added,
            "present": self.present,
            "replaced": self.replaced,
            "rejected": [list(r) for r in self.rejected],
            "duplicates": [list(d) for d in self.duplicates],
            "warnings": [list(w) for w in self.warnings],
        }


@dataclass(frozen=True)
class FailureWriter:
    """How one collection's table records a rejected or failed item; call it like a function.

    The four ingest stages record failures alike (count it, skip the write when the row already says
    the same, upsert the row with its content columns cleared); only the table, its natural key, the
    columns to clear, the columns that must not stay empty and the dependents to drop differ.
    """

    model: type[Base]
    key: tuple[str, ...]
    cleared: Mapping[str, Any]
    defaults: Mapping[str, Any] = field(default_factory=dict)
    drop_dependents: Callable[[Session, int], None] | None = None

    def __call__(
        self, url: str, summary: IngestSummary, label: str, row: Mapping[str, Any], status: str, reason: str,
        existing: Mapping[str, Any] | None,
    ) -> None:
        reason = text_line(reason)
        summary.reject(label, reason)
        if _failure_unchanged(existing, row, status, reason):
            return  # same outcome as last time: nothing to change
        values = {**row, "status": status, "error": reason, **copy.deepcopy(dict(self.cleared))}
        for column, default in self.defaults.items():
            values.setdefault(column, copy.deepcopy(default))
        with session_scope(url) as session:
            row_id = upsert(session, self.model, values, key=list(self.key))[0]
            if existing is not None and self.drop_dependents is not None:
                self.drop_dependents(session, row_id)


def _failure_unchanged(
    existing: Mapping[str, Any] | None, row: Mapping[str, Any], status: str, reason: str,
) -> bool:
    """True when the stored row already records this outcome for the same content (no write needed)."""
    return (
        existing is not None and existing["status"] == status and existing["error"] == reason
        and existing["sha256"] == row.get("sha256")
    )


@dataclass(frozen=True)
class IngestLimits:
    """Input limits; anything over them is rejected with the limit named in the reason."""

    max_shape_bytes: int = 100 * 1024 * 1024  # the original skipped ShapeNet OBJs over 50 MB
    max_faces: int = 500_000
    max_image_pixels: int = 64_000_000
    max_image_bytes: int = 256 * 1024 * 1024
    max_texture_pixels: int = 64 * 1024 * 1024
    max_exemplar_aspect: float = 20.0  # long side / short side of a product photo; strips are refused unread
    timeout_s: float = 600.0  # per shape / envmap in the isolated worker
    memory_bytes: int = 6 * 1024**3  # per shape / envmap: the isolated worker's data segment (a bomb's ceiling)
    archive: ArchiveLimits = field(default_factory=ArchiveLimits)

    @classmethod
    def from_settings(cls, settings: Any) -> IngestLimits:
        """The limits configured through PHOTOSHAPE_INGEST_* settings."""
        return cls(
            max_shape_bytes=int(settings.ingest_max_file_mb * 1024 * 1024),
            max_faces=int(settings.ingest_max_faces),
            max_image_pixels=int(settings.ingest_max_image_megapixels * 1_000_000),
        )


def existing_row(url: str, columns: Sequence[Any], *where: Any) -> dict[str, Any] | None:
    """`columns` of the row an item would replace (None: a new item), read in a session of its own: what
    the skip / replace decision and the summary's "added" or "replaced" compare against."""
    with session_scope(url) as session:
        row = session.execute(sa.select(*columns).where(*where)).first()
    return dict(row._mapping) if row is not None else None


def files_hash(paths: Iterable[Path], base: Path | None = None) -> str:
    """sha256 over (relative name, sha256 of bytes) of several files, in the given order."""
    digest = hashlib.sha256()
    for path in paths:
        name = path.name
        if base is not None:
            try:
                name = path.resolve().relative_to(base.resolve()).as_posix()
            except ValueError:
                pass
        digest.update(name.encode())
        digest.update(b"\0")
        digest.update(bytes.fromhex(sha256_file(path)))
    return digest.hexdigest()


def hash_fraction(*parts: str) -> float:
    """A deterministic number in [0, 1) from strings (used for train/val splits)."""
    digest = hashlib.sha256("/".join(parts).encode()).hexdigest()
    return int(digest[:12], 16) / float(1 << 48)


def split_for(source: str, source_id: str, val_fraction: float = 0.1) -> str:
    """Deterministic 90/10 train/val split from (source, source_id)."""
    return "val" if hash_fraction(source, source_id) < val_fraction else "train"


def resolve_settings(settings: Settings | None) -> Settings:
    return settings or get_settings()


def store_for(settings: Settings) -> BlobStore:
    return default_store(settings)


def one_line(exc: BaseException) -> str:
    """An exception as one short line (first line of its message, type name if empty)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text[:500]


def rejection_reason(exc: BaseException) -> str:
    """Why an item's reader gave up, as one line: the exception's own words, named by kind.

    Memory and recursion errors get a reason of their own, since their messages say nothing
    ("" and "maximum recursion depth exceeded") a user could act on.
    """
    if isinstance(exc, MemoryError):
        return "out of memory while reading it (over the per-item memory budget)"
    if isinstance(exc, RecursionError):
        return "nested too deeply to read"
    if isinstance(exc, OSError):
        return f"unreadable ({exc.strerror or one_line(exc)})"
    return f"{type(exc).__name__}: {one_line(exc)}"


def guard_item(summary: IngestSummary, label: str, call: Callable[[], T]) -> T | None:
    """Run one item's ingest; any exception becomes one `rejected` line and the batch goes on.

    The one guard every collection runs each item behind: the readers reject what they foresee
    with their own reasons (and rows), and this catches what they did not (a ValueError from a
    number parser, a RecursionError, a MemoryError, a decoder's own exception), so one poison
    file never ends a batch or a scheduled run. Nothing is written for such an item: its row is
    upserted last, so an exception before that leaves no partial row. The traceback goes to the
    debug log only; the console shows one line. Returns what `call` returned (None when rejected here).
    """
    try:
        return call()
    except Exception as exc:  # MemoryError and RecursionError are Exceptions too
        logger.debug("%s: rejected after an unforeseen error", text_line(label), exc_info=True)
        summary.reject(label, rejection_reason(exc))
        return None


def adopt_renamed_row(
    url: str, model: type[Base], *, source: str, source_id: str, legacy_id: str | None, source_path: str,
    sha256: str | None, batch_ids: Collection[str],
) -> int | None:
    """Give the row a file had under its former id (its stem) the file's new id; the row's id, or None.

    Source ids of plain files used to be file stems and are now paths relative to the ingested
    folder, so a re-ingest of an existing data root must update those rows, not insert duplicates
    beside them. A row is adopted when it has the file's former id and either its recorded
    `source_path` or its content (`sha256`) matches, no row holds the new id yet, and the former
    id is not itself an id of this batch (then that file owns it: two identical files in two
    folders must not take each other's rows).
    """
    if legacy_id is None or legacy_id == source_id or legacy_id in batch_ids:
        return None
    key = (model.source == source)  # type: ignore[attr-defined]
    with session_scope(url) as session:
        taken = session.execute(sa.select(model.id).where(key, model.source_id == source_id)).first()  # type: ignore[attr-defined]
        if taken is not None:
            return None
        matches = [model.source_path == source_path]  # type: ignore[attr-defined]
        if sha256:
            matches.append(model.sha256 == sha256)  # type: ignore[attr-defined]
        row_id = session.execute(
            sa.select(model.id).where(key, model.source_id == legacy_id, sa.or_(*matches))  # type: ignore[attr-defined]
        ).scalar_one_or_none()
        if row_id is None:
            return None
        session.execute(sa.update(model).where(model.id == row_id).values(source_id=source_id))  # type: ignore[attr-defined]
    logger.info("%s %d: source_id %r is now %r (ids are paths relative to the ingested folder)",
                model.__tablename__, row_id, legacy_id, source_id)
    return row_id
