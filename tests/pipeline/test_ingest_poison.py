"""No poison pill: one hostile file costs one `rejected` line, never the batch, the run or the machine.

Through the real thing: `photoshape run ingest` on an inbox holding poison beside good inputs, the
ingest functions on files written here, and a child process that measures the memory and time a
decompression-bomb strip costs before it is refused.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from tests.geometry.makers import write_png
from tests.imaging.test_exemplar import photo
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.ingest.common import IngestSummary, guard_item, rejection_reason

runner = CliRunner()


def _strip_png(path: Path, width: int = 80_000, height: int = 2) -> Path:
    """A ~240-byte PNG of a black strip: few pixels, but its square would be width^2."""
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.zeros((height, width), np.uint8)).save(path)
    return path


def _material(folder: Path, sidecar: str | None = None, name: str = "material.json") -> Path:
    write_png(folder / "albedo.png", np.full((4, 4, 3), 120, np.uint8))
    if sidecar is not None:
        (folder / name).write_text(sidecar)
    return folder


def test_guard_turns_any_exception_into_one_rejected_line() -> None:
    summary = IngestSummary("materials")

    def explode(exc: BaseException) -> None:
        raise exc

    assert guard_item(summary, "a", lambda: 7) == 7
    for exc in (ValueError("Exceeds the limit (4300 digits)"), RecursionError("maximum recursion depth"),
                MemoryError(), KeyError("x"), OSError(13, "Permission denied")):
        assert guard_item(summary, "b\nc", lambda exc=exc: explode(exc)) is None
    reasons = [reason for _, reason in summary.rejected]
    assert reasons == ["ValueError: Exceeds the limit (4300 digits)", "nested too deeply to read",
                       "out of memory while reading it (over the per-item memory budget)", "KeyError: 'x'",
                       "unreadable (Permission denied)"]
    assert all(label == "b c" for label, _ in summary.rejected)  # one safe line


def test_guard_lets_interrupts_through() -> None:
    with pytest.raises(KeyboardInterrupt):
        guard_item(IngestSummary("shapes"), "a", lambda: (_ for _ in ()).throw(KeyboardInterrupt()))


def test_rejection_reason_is_one_line() -> None:
    assert rejection_reason(RuntimeError("first\nsecond")) == "RuntimeError: first"


def test_an_unforeseen_reader_error_costs_one_item(db_url: str, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Whatever a reader raises that nobody foresaw, the next folder is still ingested."""
    from photoshape_flow.ingest import materials as ingest_materials

    real = ingest_materials.scan_material

    def scan(folder: Path, **kwargs: object):  # type: ignore[no-untyped-def]
        if folder.name == "wood_a":
            raise RecursionError("maximum recursion depth exceeded")
        return real(folder, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(ingest_materials, "scan_material", scan)
    _material(tmp_path / "wood_a")
    _material(tmp_path / "wood_b")
    summary = ingest_materials.ingest_materials([tmp_path], previews=False)
    assert len(summary.added) == 1 and summary.rejected == [(str(tmp_path / "wood_a"), "nested too deeply to read")]


def test_run_with_poison_in_the_inbox_ingests_the_rest_and_exits_2(db_url: str, settings_env: Path) -> None:
    inbox = settings_env / "inbox"
    _material(inbox / "materials" / "wood_digits", '{"substance": "wood", "scale": ' + "9" * 5000 + "}")
    _material(inbox / "materials" / "wood_toml", 'substance = "wood"\nscale = ' + "9" * 5000, "material.toml")
    _material(inbox / "materials" / "wood_good")
    _strip_png(inbox / "exemplars" / "strip.png")
    write_png(inbox / "exemplars" / "good.png", photo(width=96, height=64, box=(30, 10, 60, 50)))
    result = runner.invoke(app, ["run", "ingest", "-p", "tiny"])
    output = " ".join(result.output.split())
    assert result.exit_code == 2, output
    assert "Traceback" not in output and "3 inputs rejected at ingest" in output, output
    assert "wood_digits: material.json: a number with 5000 digits (limit 24)" in output, output
    assert "wood_toml: material.toml: a number with more than 4300 digits" in output, output
    assert "strip.png: 80000x2 pixels: aspect ratio 40000:1" in output, output
    with session_scope(db_url) as session:
        ok = session.execute(sa.select(m.Material.name).where(m.Material.status == "ok")).scalars().all()
        photos = session.execute(sa.select(m.Exemplar.source_id).where(m.Exemplar.status == "ok")).scalars().all()
        run = session.execute(sa.select(m.PipelineRun)).scalar_one()
    assert ok == ["wood_good"] and photos == ["good"]
    assert run.status == "ok" and run.reports["ingest"]["rejected"] == 3  # recorded, and the run went on


def test_the_80000x2_strip_is_refused_fast_in_little_memory(db_url: str, tmp_path: Path) -> None:
    """Measured in a child process: its peak RSS (VmHWM: reset by exec, unlike ru_maxrss, which a child
    forked from a big pytest process inherits) includes the imports, and still stays under 500 MB."""
    strip = _strip_png(tmp_path / "in" / "strip.png")
    assert strip.stat().st_size < 1000
    script = textwrap.dedent(f"""
        import json, re, time
        from pathlib import Path
        from photoshape_flow.ingest.ingest import ingest_exemplars
        start = time.perf_counter()
        summary = ingest_exemplars([{str(strip)!r}])
        seconds = time.perf_counter() - start
        status = Path("/proc/self/status").read_text()
        peak_mb = int(re.search(r"VmHWM:\\s+(\\d+) kB", status).group(1)) / 1024
        print(json.dumps({{"rejected": summary.rejected, "seconds": seconds, "peak_mb": peak_mb}}))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True)
    measured = json.loads(done.stdout.strip().splitlines()[-1])
    assert measured["rejected"] == [[str(strip), "80000x2 pixels: aspect ratio 40000:1 exceeds the limit of 20:1"]]
    assert measured["seconds"] < 1.0 and measured["peak_mb"] < 500, measured


def test_a_strip_inside_the_aspect_limit_is_cropped_without_its_square() -> None:
    """A 20:1 strip whose foreground spans 10000 pixels: the crop never allocates 10000^2 (400 MB with its mask)."""
    from photoshape_flow.imaging.exemplar import ExemplarOptions, prepare_exemplar

    rgb = np.full((500, 10_000, 3), 255, np.uint8)
    rgb[200:300, 10:9_990] = 40
    tracemalloc.start()
    try:
        prepared = prepare_exemplar(rgb, ExemplarOptions(size=256))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert prepared.image.shape == (256, 256, 3) and prepared.crop["side"] == 9_980
    assert peak < 200 * 1024 * 1024, peak  # what the photo itself costs; the square alone would be 300 MB
    assert prepared.image[128, 128].tolist() == [40, 40, 40] and prepared.image[5, 128].tolist() == [255, 255, 255]
    assert prepared.mask[128, 128] == 255 and prepared.mask[5, 128] == 0


def test_a_photo_rewritten_while_being_read_is_refused(db_url: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A writer replaces the photo between its hashing and its decoding: refused, not stored under a wrong hash."""
    from photoshape_flow.ingest import exemplars as ingest_exemplars

    path = write_png(tmp_path / "in" / "a.png", photo(width=96, height=64, box=(30, 10, 60, 50)))
    real = ingest_exemplars.read_image

    def read_during_a_rewrite(*args: object, **kwargs: object):  # type: ignore[no-untyped-def]
        write_png(path, photo(width=96, height=64, box=(20, 5, 70, 55)))  # the concurrent writer
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(ingest_exemplars, "read_image", read_during_a_rewrite)
    summary = ingest_exemplars.ingest_exemplars([tmp_path / "in"])
    assert summary.rejected == [(str(path), "a.png changed while being read; ingest it again once it is "
                                            "completely written")]
    monkeypatch.setattr(ingest_exemplars, "read_image", real)
    assert len(ingest_exemplars.ingest_exemplars([tmp_path / "in"]).added) == 1  # once it is still, it goes in


def test_a_material_map_rewritten_while_being_read_is_refused(db_url: str, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.ingest import materials as ingest_materials

    folder = _material(tmp_path / "wood_a")
    real = ingest_materials.load_maps

    def load_during_a_rewrite(*args: object, **kwargs: object):  # type: ignore[no-untyped-def]
        write_png(folder / "albedo.png", np.full((8, 8, 3), 10, np.uint8))
        return real(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(ingest_materials, "load_maps", load_during_a_rewrite)
    summary = ingest_materials.ingest_materials([folder], previews=False)
    assert summary.rejected == [(str(folder), "albedo.png changed while being read; ingest it again once it is "
                                              "completely written")]
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Material)).scalar_one()
    assert row.status == "rejected" and row.maps == {}
