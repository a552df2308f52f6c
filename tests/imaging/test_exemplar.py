"""Exemplar cleaning: white-background mask, tight square crop with padding, resize, rejections."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.imaging.exemplar import ExemplarOptions, foreground_mask, prepare_exemplar
from photoshape_flow.imaging.io import BadImageError, read_image


def photo(width: int = 300, height: int = 200, box: tuple[int, int, int, int] = (100, 50, 160, 170),
          seed: int = 0) -> np.ndarray:
    """A noisy near-white photo with a shaded object in `box` = (x0, y0, x1, y1)."""
    rng = np.random.default_rng(seed)
    image = np.clip(250 + rng.normal(0, 2, (height, width, 3)), 0, 255)
    x0, y0, x1, y1 = box
    ramp = np.linspace(60, 140, x1 - x0)[None, :, None]
    image[y0:y1, x0:x1] = ramp + rng.normal(0, 3, (y1 - y0, x1 - x0, 3))
    image[y0:y1, x0:x1, 0] += 30
    return np.clip(image, 0, 255).astype(np.uint8)


def test_mask_and_tight_square_crop() -> None:
    prepared = prepare_exemplar(photo(), ExemplarOptions(size=64))
    assert prepared.meta["bbox"] == [100, 50, 160, 170]
    assert prepared.crop == {"x0": 70, "y0": 50, "side": 120}  # square around the box, centred
    assert prepared.image.shape == (64, 64, 3) and prepared.mask.shape == (64, 64)
    assert prepared.native_width == 300 and prepared.native_height == 200
    # the object spans the full height and half the width of the crop
    cols = np.nonzero(prepared.mask.any(axis=0))[0]
    assert cols.min() == pytest.approx(16, abs=1) and cols.max() == pytest.approx(47, abs=1)
    assert prepared.foreground_fraction == pytest.approx(0.5, abs=0.03)


def test_crop_leaving_the_photo_is_padded_white_and_maps_native_coordinates() -> None:
    image = photo(box=(0, 10, 40, 190))  # tall object at the left border
    prepared = prepare_exemplar(image, ExemplarOptions(size=1000))
    crop = prepared.crop
    assert crop["side"] == 180 and crop["x0"] < 0
    assert prepared.image.shape[0] == 180  # never upscaled beyond the native crop
    assert (prepared.image[:, : -crop["x0"]] == 255).all()  # padding is pure white
    # a native pixel maps into the stored frame by (p - x0) * stored / side
    x, y = 20, 100
    sx = int((x - crop["x0"]) * prepared.image.shape[1] / crop["side"])
    sy = int((y - crop["y0"]) * prepared.image.shape[0] / crop["side"])
    assert np.array_equal(prepared.image[sy, sx], image[y, x])


def test_jpeg_specks_do_not_widen_the_crop() -> None:
    image = photo()
    image[5, 5] = 0  # a single dark pixel in a corner
    assert prepare_exemplar(image).meta["bbox"] == [100, 50, 160, 170]


@pytest.mark.parametrize(
    ("image", "reason"),
    [
        (np.full((100, 100, 3), 255, np.uint8), "no foreground"),
        (np.full((100, 100, 3), 30, np.uint8), "no foreground"),
        (np.clip(250 + np.random.default_rng(0).normal(0, 2, (80, 80, 3)), 0, 255).astype(np.uint8), "no foreground"),
        (photo(box=(10, 10, 12, 12)), "too small"),
        (np.clip(photo() * 0 + np.linspace(0, 120, 300)[None, :, None], 0, 255).astype(np.uint8), "not near-white"),
    ],
    ids=["white", "black", "noise-only", "tiny", "dark-background"],
)
def test_rejections(image: np.ndarray, reason: str) -> None:
    with pytest.raises(BadImageError, match=reason):
        prepare_exemplar(image)


def test_threshold_sits_between_darkest_and_brightest_level() -> None:
    image = photo()
    mask, threshold = foreground_mask(image)
    assert 150 < threshold < 240
    assert mask[100, 130] and not mask[10, 10]


@pytest.mark.realdata
def test_real_abo_photos(shared_data: Path) -> None:
    photos = sorted((shared_data / "photos" / "abo").glob("*.jpg"))
    assert photos
    for path in photos:
        rgb, _ = read_image(path)
        prepared = prepare_exemplar(rgb, ExemplarOptions(size=512))
        side = prepared.crop["side"]
        assert prepared.image.shape[0] == min(512, side)
        assert 0.05 < prepared.foreground_fraction < 0.95, path.name
        assert side <= max(rgb.shape[:2]) + 2
