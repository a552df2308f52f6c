"""The oracle's partial degradation (`deg:<parts>`) splits the exemplar degradation without changing it."""

from __future__ import annotations

import numpy as np
import pytest
from experiments.fit_oracle.run import DEGRADATION_PARTS, clean_photo, partly_degraded

from photoshape_flow.pipeline.fit_calibration import as_photo


def _render() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    hdr = rng.uniform(0.0, 1.2, (40, 40, 3)).astype(np.float32)
    ids = np.ones((40, 40), np.int32)
    ids[:6] = 0
    return hdr, ids


def test_all_parts_are_the_whole_degradation_and_none_is_the_clean_photo() -> None:
    hdr, ids = _render()
    assert np.array_equal(partly_degraded(hdr, ids, 11, set(DEGRADATION_PARTS)), as_photo(hdr, ids, 11))
    assert np.array_equal(partly_degraded(hdr, ids, 11, set()), clean_photo(hdr, ids))


def test_one_part_changes_the_photo_and_an_unknown_part_is_refused() -> None:
    hdr, ids = _render()
    clean = clean_photo(hdr, ids).astype(int)
    balanced = partly_degraded(hdr, ids, 11, {"wb"}).astype(int)
    assert np.abs(balanced - clean).max() > 0
    with pytest.raises(SystemExit, match="unknown part 'gamma'"):
        partly_degraded(hdr, ids, 11, {"gamma"})
