"""Duplicate detection: the dense HOG separates copies from different photos; exact range search."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from tests.imaging.test_exemplar import photo

from photoshape_flow.imaging.dedupe import DEFAULT_RADIUS, assign_duplicates, dense_hog, range_search
from photoshape_flow.imaging.exemplar import prepare_exemplar
from photoshape_flow.imaging.io import read_image


def _reencode(rgb: np.ndarray, scale: float = 1.0, quality: int = 70) -> np.ndarray:
    image = Image.fromarray(rgb)
    if scale != 1.0:
        image = image.resize((int(rgb.shape[1] * scale), int(rgb.shape[0] * scale)), Image.LANCZOS)
    buffer = io.BytesIO()
    image.save(buffer, "JPEG", quality=quality)
    return np.asarray(Image.open(buffer).convert("RGB"))


def test_range_search_matches_brute_force() -> None:
    rng = np.random.default_rng(1)
    base = rng.normal(size=(50, 16)).astype(np.float32)
    queries = np.concatenate([base[:10] + rng.normal(0, 0.01, (10, 16)), rng.normal(size=(5, 16))]).astype(np.float32)
    hits = range_search(queries, base, 0.5, block=7)
    brute = {(i, j) for i in range(len(queries)) for j in range(len(base))
             if np.linalg.norm(queries[i] - base[j]) < 0.5}
    assert {(i, j) for i, j, _ in hits} == brute
    assert {(i, j) for i, j, _ in hits} >= {(k, k) for k in range(10)}


def test_assign_duplicates_points_every_duplicate_at_an_original() -> None:
    a, b = np.eye(3, dtype=np.float32)[:2]
    existing = a[None]
    new = np.stack([a, b, b, a]).astype(np.float32)
    result = assign_duplicates(new, existing, 0.1)
    assert result[0] is not None and result[0].existing and result[0].index == 0
    assert result[1] is None  # original
    assert result[2] is not None and not result[2].existing and result[2].index == 1
    assert result[3] is not None and result[3].existing


def test_copies_fall_under_the_paper_threshold_and_different_objects_do_not() -> None:
    original = prepare_exemplar(photo(box=(100, 50, 160, 170))).image
    copy = prepare_exemplar(_reencode(photo(box=(100, 50, 160, 170)), 1.25)).image
    other = prepare_exemplar(photo(box=(60, 60, 240, 120), seed=3)).image
    f0, f1, f2 = dense_hog(original), dense_hog(copy), dense_hog(other)
    assert np.linalg.norm(f0) == pytest.approx(1.0)
    assert np.linalg.norm(f0 - f1) < DEFAULT_RADIUS
    assert np.linalg.norm(f0 - f2) > DEFAULT_RADIUS


@pytest.mark.realdata
def test_real_photos_re_encoded_are_duplicates(shared_data: Path) -> None:
    photos = sorted((shared_data / "photos" / "abo").glob("*.jpg"))
    originals, copies = [], []
    for path in photos:
        rgb, _ = read_image(path)
        originals.append(dense_hog(prepare_exemplar(rgb).image))
        copies.append(dense_hog(prepare_exemplar(_reencode(rgb, 1.25, 85)).image))
    result = assign_duplicates(np.stack(copies), np.stack(originals))
    assert all(r is not None and r.existing and r.index == i for i, r in enumerate(result))
    assert all(r is None for r in assign_duplicates(np.stack(originals), np.zeros((0, 441), np.float32)))
