"""`photoshape_flow.inputs`: source ids from folder trees, and every unusable path named."""

from __future__ import annotations

import unicodedata
from pathlib import Path

from photoshape_flow.inputs import source_id_for, walk_inputs


def test_source_ids_are_nfc_relative_paths_without_extension(tmp_path: Path) -> None:
    decomposed = "cafe\u0301"  # as macOS file systems write "café"
    assert source_id_for(tmp_path / "a" / decomposed / "chair.obj", tmp_path) == "a/caf\u00e9/chair"
    assert source_id_for(tmp_path / f"{decomposed}.v2.obj", None) == unicodedata.normalize("NFC", f"{decomposed}.v2")
    assert source_id_for(Path("/elsewhere/chair.obj"), tmp_path) == "chair"  # not under the root: its stem


def test_walk_names_what_it_cannot_use_and_stays_quiet_about_companions(tmp_path: Path) -> None:
    (tmp_path / "m" / "a").mkdir(parents=True)
    (tmp_path / "m" / "a" / "chair.obj").write_text("v 0 0 0\n")
    (tmp_path / "m" / "a" / "chair.mtl").write_text("")
    (tmp_path / "m" / "box.obj").mkdir()
    (tmp_path / "empty").mkdir()
    found = list(walk_inputs([tmp_path / "m", tmp_path / "empty", tmp_path / "x.txt"], {".obj"}))
    assert [(f.path.relative_to(tmp_path).as_posix(), f.source_id if f.reason is None else f.reason)
            for f in found] == [
        ("m/a/chair.obj", "a/chair"),
        ("m/box.obj", "a folder, not a file (its name ends like a supported file)"),
        ("empty", "no .obj files in this folder"),
        ("x.txt", "no such file or folder"),
    ]
