"""Fuzzing every reader with generated hostile inputs: an `ok` row or one `rejected` line, nothing else.

For each reader (material sidecars in JSON and TOML, OBJ/MTL, glTF/GLB, Sweet Home 3D catalogs,
photos, HDR/EXR envmaps, ground-truth files) Hypothesis draws inputs from at least ten hostile
kinds (`tests.fuzz.hostile`), writes them to a fresh folder and runs the real ingest function (or
the ground-truth reader) on it, under a memory cap. The property, per example:

- the call returns (no exception escapes: no traceback, no batch ended) within `SECONDS`;
- each item comes back once: `ok` (added / present / replaced) or exactly one `rejected` line,
  on one line, whose reason is never an out-of-memory (the limits must refuse a bomb first);
- rows are never partial: every `ok` row's blobs exist, and no more rows are failed than lines say;
- no log record carries a traceback at warning level or above;
- the process's peak resident memory grows by less than `PEAK_MB` (VmHWM, reset before each
  example), with RLIMIT_DATA as the hard ceiling behind it.

Each kind is its own test (so every kind is drawn, and a failure names it); the examples are
derandomised (a fixed seed per test) and bounded, so the harness runs in about a minute on two
cores. `test_every_reader_has_ten_kinds` keeps the kinds from shrinking unnoticed.
"""

from __future__ import annotations

import itertools
import logging
import resource
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from hypothesis import HealthCheck, given, settings
from tests.fuzz.hostile import READERS, Files

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.store import BlobStore

pytestmark = pytest.mark.fuzz

EXAMPLES = 10  # per kind (each reader has 11 or more kinds): over 100 examples per reader
PEAK_MB = 768  # growth of the peak resident set during one example
CEILING_MB = 3072  # RLIMIT_DATA headroom over the data segment before the example: the hard stop
SECONDS = 15.0  # one example, however hostile
FUZZ = settings(max_examples=EXAMPLES, derandomize=True, database=None, deadline=None, print_blob=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])


def _status_kb(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


@contextmanager
def memory_watch() -> Iterator[dict[str, float]]:
    """The peak RSS growth (MB) of the block, with RLIMIT_DATA lowered to a ceiling for its duration."""
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current RSS
    before = _status_kb("VmRSS")
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    ceiling = (_status_kb("VmData") + CEILING_MB * 1024) * 1024
    resource.setrlimit(resource.RLIMIT_DATA, (ceiling if hard == resource.RLIM_INFINITY else min(ceiling, hard), hard))
    measured: dict[str, float] = {}
    try:
        yield measured
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))
        measured["peak_mb"] = (_status_kb("VmHWM") - before) / 1024


class TracebackRecords(logging.Handler):
    """Collects log records that would print a traceback (warning or above, with exc_info)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info:
            self.records.append(record)


@dataclass
class Harness:
    root: Path
    url: str
    store: BlobStore
    counter: Iterator[int] = field(default_factory=itertools.count)

    def write(self, files: dict[str, bytes], folder: Path) -> Path:
        folder.mkdir(parents=True)
        for relative, data in files.items():
            path = folder / relative
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        return folder


@pytest.fixture
def harness(db_url: str, store: BlobStore, tmp_path: Path) -> Iterator[Harness]:
    handler = TracebackRecords()
    package = logging.getLogger("photoshape_flow")
    package.addHandler(handler)
    try:
        yield Harness(tmp_path / "cases", db_url, store)
    finally:
        package.removeHandler(handler)
    assert not handler.records, [(r.getMessage(), r.exc_info) for r in handler.records[:3]]


def check_summary(summary: Any) -> None:
    """Each item once, each rejection one clean line, no out-of-memory, nothing partial."""
    labels = [label for label, _ in summary.rejected]
    assert len(labels) == len(set(labels)), summary.rejected  # exactly one line per rejected item
    assert summary.total >= 1, summary.as_dict()
    for label, reason in summary.rejected:
        assert reason and "\n" not in reason and "\n" not in label, (label, reason)
        assert "out of memory" not in reason and "MemoryError" not in reason, (label, reason)
        assert "Traceback" not in reason, reason
    ok = set(summary.added) | set(summary.present) | set(summary.replaced)
    assert len(ok) == len(summary.added) + len(summary.present) + len(summary.replaced), summary.as_dict()


def check_rows(url: str, store: BlobStore, model: type, where: Any, blobs: Callable[[Any], list[str | None]],
               summary: Any) -> None:
    """`ok` rows hold every blob they name; rows that are not ok are no more than the rejected lines."""
    with session_scope(url) as session:
        rows = session.execute(sa.select(model).where(where)).scalars().all()
        for row in rows:
            if row.status == "ok":
                refs = blobs(row)
                assert refs and all(ref and store.exists(ref) for ref in refs), (row.id, refs)
            else:
                assert row.error and "\n" not in row.error, (row.id, row.error)
        failed = sum(1 for row in rows if row.status != "ok")
    assert failed <= len(summary.rejected), (failed, summary.rejected)


def run_case(harness: Harness, files: Files, ingest: Callable[[Path, int], Any]) -> Any:
    """Write one drawn case, run `ingest(folder, n)` on it under the memory watch, check time and memory."""
    n = next(harness.counter)
    folder = harness.write(files, harness.root / f"c{n}")
    start = time.perf_counter()
    with memory_watch() as memory:
        result = ingest(folder, n)
    seconds = time.perf_counter() - start
    assert seconds < SECONDS, seconds
    assert memory["peak_mb"] < PEAK_MB, memory
    return result


def fuzz(harness: Harness, reader: str, kind: str, ingest: Callable[[Path, int], Any]) -> None:
    """Hypothesis over one kind of one reader, each example through `run_case`."""
    @FUZZ
    @given(files=READERS[reader]()[kind])
    def examples(files: Files) -> None:
        run_case(harness, files, ingest)

    examples()


def cases(*readers: str) -> list[tuple[str, str]]:
    """(reader, kind) for every kind of the given readers: the parameters of a fuzz test."""
    return [(reader, kind) for reader in readers for kind in sorted(READERS[reader]())]


def test_every_reader_has_ten_kinds() -> None:
    assert {reader: len(READERS[reader]()) >= 10 for reader in READERS} == dict.fromkeys(READERS, True)


def _material_blobs(row: m.Material) -> list[str | None]:
    return list((row.maps or {}).values()) if row.kind == "svbrdf" else ["analytic"]


@pytest.mark.parametrize(("reader", "kind"), cases("json_sidecars", "toml_sidecars"))
def test_material_sidecars(harness: Harness, reader: str, kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.ingest.ingest import ingest_materials

    monkeypatch.setattr(BlobStore, "exists", _exists_or_analytic(BlobStore.exists))

    def ingest(folder: Path, n: int) -> None:
        material = folder.rename(folder.with_name(f"wood_{n}"))
        summary = ingest_materials([material], previews=False)
        check_summary(summary)
        check_rows(harness.url, harness.store, m.Material, m.Material.source_path == str(material.resolve()),
                   _material_blobs, summary)

    fuzz(harness, reader, kind, ingest)


def _exists_or_analytic(exists: Callable[[BlobStore, str], bool]) -> Callable[[BlobStore, str], bool]:
    """An analytic material names no blob; its marker counts as present."""
    return lambda self, ref: ref == "analytic" or exists(self, ref)


@pytest.mark.parametrize(("reader", "kind"), cases("objs", "gltfs", "sh3fs"))
def test_shapes(harness: Harness, reader: str, kind: str) -> None:
    from photoshape_flow.ingest.ingest import ingest_shapes

    def ingest(folder: Path, n: int) -> None:
        summary = ingest_shapes([folder], source=f"fuzz{n}", isolate=False)
        check_summary(summary)
        check_rows(harness.url, harness.store, m.Shape, m.Shape.source.in_([f"fuzz{n}", "sweethome3d"])
                   & m.Shape.source_path.startswith(str(folder.resolve())), lambda row: [row.mesh_blob], summary)

    fuzz(harness, reader, kind, ingest)


@pytest.mark.parametrize(("reader", "kind"), cases("images"))
def test_photos(harness: Harness, reader: str, kind: str) -> None:
    from photoshape_flow.ingest.ingest import ingest_exemplars

    def ingest(folder: Path, n: int) -> None:
        summary = ingest_exemplars([folder], source=f"fuzz{n}", size=64)
        check_summary(summary)
        check_rows(harness.url, harness.store, m.Exemplar, m.Exemplar.source == f"fuzz{n}",
                   lambda row: [row.image_blob, row.mask_blob], summary)

    fuzz(harness, reader, kind, ingest)


@pytest.mark.parametrize(("reader", "kind"), cases("envmaps"))
def test_envmaps(harness: Harness, reader: str, kind: str) -> None:
    from photoshape_flow.ingest.ingest import ingest_envmaps

    def ingest(folder: Path, n: int) -> None:
        for path in list(folder.iterdir()):
            path.rename(path.with_name(f"sky{n}{path.suffix}"))
        summary = ingest_envmaps([folder], isolate=False)
        check_summary(summary)
        check_rows(harness.url, harness.store, m.Envmap, m.Envmap.name == f"sky{n}", lambda row: [row.blob], summary)

    fuzz(harness, reader, kind, ingest)


@pytest.mark.parametrize(("reader", "kind"), cases("groundtruths"))
def test_groundtruth_files(harness: Harness, reader: str, kind: str) -> None:
    """The reader's outcome is a parsed file (with one-line problems) or one GroundTruthError line."""
    from photoshape_flow.evaluation.groundtruth import GroundTruthError, read_groundtruth_file

    def read(folder: Path, _n: int) -> None:
        (path,) = list(folder.iterdir())
        try:
            parsed = read_groundtruth_file(path)
        except GroundTruthError as exc:
            assert str(exc) and "\n" not in str(exc), str(exc)
            return
        assert all("\n" not in problem for problem in parsed.problems), parsed.problems

    fuzz(harness, reader, kind, read)
