"""Validation renders framed like exemplars, and their part maps misaligned like fine alignment's."""

from __future__ import annotations

import numpy as np

from photoshape_flow.fit.validation import Misalignment, frame, misalign, resampled, sample_misalignment


def _labels() -> np.ndarray:
    labels = np.zeros((40, 40), np.uint16)
    labels[10:20, 8:32] = 1
    labels[20:34, 12:28] = 2
    return labels


def test_shift_moves_the_map_and_keeps_its_labels() -> None:
    moved = misalign(_labels(), Misalignment(dx=2, dy=-1, scale=1.0, boundary=0))
    assert np.array_equal(moved[9:19, 10:34], _labels()[10:20, 8:32])
    assert set(np.unique(moved)) == {0, 1, 2}


def test_erosion_drops_every_boundary_and_dilation_grows_only_into_background() -> None:
    labels = _labels()
    eroded = misalign(labels, Misalignment(0, 0, 1.0, -1))
    assert eroded[19, 20] == 0 and eroded[20, 20] == 0 and eroded[15, 20] == 1  # the seat/legs border is gone
    assert (eroded > 0).sum() < (labels > 0).sum()
    grown = misalign(labels, Misalignment(0, 0, 1.0, 1))
    assert (grown > 0).sum() > (labels > 0).sum() and np.array_equal(grown[labels > 0], labels[labels > 0])


def test_sampled_errors_are_deterministic_and_small() -> None:
    a = [sample_misalignment(np.random.default_rng(5), 128) for _ in range(2)]
    assert a[0] == a[1]
    errors = [sample_misalignment(np.random.default_rng(s), 48) for s in range(50)]
    assert max(max(abs(e.dx), abs(e.dy)) for e in errors) == 1  # 2 px at 128 px is 1 px at 48
    assert all(0.96 < e.scale < 1.04 for e in errors) and {e.boundary for e in errors} == {-1, 0, 1}


def test_frame_crops_the_silhouette_square() -> None:
    image = np.full((40, 40, 3), 255, np.uint8)
    image[_labels() > 0] = 90
    rgb, ids, fg = frame(image, _labels(), 24)
    assert rgb.shape == (24, 24, 3) and ids.shape == fg.shape == (24, 24)
    assert fg[:, 0].any() and fg[:, -1].any()  # the wider side fills the frame
    assert rgb[fg].mean() < 120 and rgb[~fg].mean() > 200


def test_resampled_keeps_the_part_ids_and_the_render_at_the_new_size() -> None:
    labels = _labels()
    hdr = np.where(labels[..., None] > 0, 0.4, 1.0).astype(np.float32) * np.ones(3, np.float32)
    big_hdr, big_ids = resampled(hdr, labels, 100)
    assert big_hdr.shape == (100, 100, 3) and big_ids.shape == (100, 100)
    assert set(np.unique(big_ids)) == {0, 1, 2} and big_ids[30, 50] == 1 and big_ids[0, 0] == 0
    assert abs(float(big_hdr.mean()) - float(hdr.mean())) < 0.02
    small_hdr, small_ids = resampled(hdr, labels, 20)  # down as well: the exemplars may be smaller
    assert small_ids.shape == (20, 20) and set(np.unique(small_ids)) == {0, 1, 2}
