"""`newest_groundtruth`: what `photoshape eval` and the bench scripts score against by default."""

from __future__ import annotations

import os
from pathlib import Path

from photoshape_flow.demo import newest_groundtruth


def test_the_most_recently_written_demo_wins_not_the_name(tmp_path: Path) -> None:
    assert newest_groundtruth(tmp_path) is None  # no demo folder at all
    older, newer = tmp_path / "demo" / "tiny", tmp_path / "demo" / "medium"
    for folder, mtime in ((older, 1_000_000), (newer, 2_000_000)):
        folder.mkdir(parents=True)
        (folder / "groundtruth.json").write_text("{}")
        os.utime(folder / "groundtruth.json", (mtime, mtime))
    assert newest_groundtruth(tmp_path) == newer / "groundtruth.json"  # "tiny" sorts last by name
    os.utime(older / "groundtruth.json", (3_000_000, 3_000_000))
    assert newest_groundtruth(tmp_path) == older / "groundtruth.json"
