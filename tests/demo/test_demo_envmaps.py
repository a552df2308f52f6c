"""Studio environment maps: float32 equirectangular .hdr files, deterministic, normalised."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from photoshape_flow.demo.envmaps import MEAN_RADIANCE, directions, render_studio, studio_specs, write_studio


def test_studio_file_is_equirectangular_float_hdr(tmp_path: Path) -> None:
    spec = studio_specs(0, 1, "studio")[0]
    path = write_studio(tmp_path / "s.hdr", spec, width=128)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.float32 and image.shape == (64, 128, 3)
    assert image.min() >= 0 and image.max() > 3 * np.median(image)  # soft boxes stand out
    first = path.read_bytes()
    write_studio(tmp_path / "t.hdr", studio_specs(0, 1, "studio")[0], width=128)
    assert (tmp_path / "t.hdr").read_bytes() == first
    write_studio(tmp_path / "u.hdr", studio_specs(1, 1, "studio")[0], width=128)
    assert (tmp_path / "u.hdr").read_bytes() != first


def test_mean_radiance_and_wrap() -> None:
    spec = studio_specs(0, 2, "studio")[1]
    image = render_studio(spec, width=128).astype(np.float64)
    h = image.shape[0]
    weight = np.sin((np.arange(h) + 0.5) / h * np.pi)[:, None]
    lum = image @ np.array([0.2126, 0.7152, 0.0722])
    assert (lum * weight).sum() / (weight.sum() * image.shape[1]) == pytest.approx(MEAN_RADIANCE, rel=1e-3)
    # azimuth wraps: the first and last columns are neighbours on the sphere
    assert np.abs(image[:, 0] - image[:, -1]).mean() <= np.abs(np.diff(image, axis=1)).mean(axis=(0, 2)).max()
    assert image[: h // 4].mean() > image[-h // 4 :].mean()  # ceiling brighter than floor


def test_directions_are_unit_and_up_first() -> None:
    d = directions(64)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    assert d[0, :, 1].min() > 0.9 and d[-1, :, 1].max() < -0.9
