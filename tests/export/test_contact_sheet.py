"""The contact sheet shows the best candidates first, one row each, with the images in their columns."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from tests.export.tiny import write_png

from photoshape_flow.export.contact_sheet import contact_sheet
from photoshape_flow.export.gallery import GalleryEntry, GalleryPart


def _entry(tmp_path, pair_id: int, score: float, colour: tuple[int, int, int], renders: bool = True) -> GalleryEntry:
    solid = np.zeros((40, 30, 3), np.uint8)
    solid[:] = colour
    views = [(v, write_png(tmp_path / f"{pair_id}-{v}.png", solid)) for v in ("exemplar", "turntable-00")]
    return GalleryEntry(pair_id=pair_id, method_key="classifier:1", shape_name=f"s{pair_id}", exemplar_name="e",
                        parts=[GalleryPart(1, "seat", 1, "oak", "wood", score)],
                        exemplar_image=write_png(tmp_path / f"ex{pair_id}.png", solid),
                        renders=views if renders else [])


def test_rows_sorted_by_score_and_tiles_placed(tmp_path):
    entries = [_entry(tmp_path, 1, 0.2, (0, 0, 250)), _entry(tmp_path, 2, 0.9, (0, 250, 0)),
               _entry(tmp_path, 3, 0.5, (250, 0, 0), renders=False)]
    out = contact_sheet(entries, tmp_path / "sheet.png", rows=5, turntable=2, tile=50, pad=5)
    sheet = np.asarray(Image.open(out).convert("RGB"))
    assert sheet.shape == (24 + 2 * (50 + 18 + 5) + 5, 5 * 50 + 6 * 5, 3)  # entry 3 has no renders: left out
    first_exemplar = sheet[24 + 25, 5 + 25]  # centre of row 0, column 0: the 0.9 candidate (green)
    second_exemplar = sheet[24 + 73 + 25, 5 + 25]
    assert tuple(first_exemplar) == (0, 250, 0) and tuple(second_exemplar) == (0, 0, 250)
    builtin = sheet[24 + 25, 5 + 55 + 25]  # no built-in render: a grey placeholder, not a crash
    assert tuple(builtin) == (235, 235, 235)


def test_no_renders_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="publish"):
        contact_sheet([_entry(tmp_path, 1, 0.5, (1, 2, 3), renders=False)], tmp_path / "x.png")
