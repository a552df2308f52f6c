"""Environment map validation: header size, aspect, finite and non-negative values, EXR and HDR."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.imaging.hdr import BadEnvmapError, header_size, read_hdr, validate_envmap


def write_hdr(path: Path, array: np.ndarray) -> Path:
    import cv2

    assert cv2.imwrite(str(path), np.ascontiguousarray(array[..., ::-1], np.float32))
    return path


def write_exr(path: Path, array: np.ndarray) -> Path:
    import mitsuba as mi

    mi.Bitmap(np.ascontiguousarray(array, np.float32)).write(str(path))
    return path


def sky(width: int = 64, height: int = 32) -> np.ndarray:
    rows = np.linspace(2.0, 0.1, height, dtype=np.float32)[:, None, None]
    return np.broadcast_to(rows, (height, width, 3)).copy()


def test_valid_hdr_and_exr(tmp_path: Path) -> None:
    for path in (write_hdr(tmp_path / "a.hdr", sky()), write_exr(tmp_path / "b.exr", sky())):
        assert header_size(path) == (64, 32)
        info = validate_envmap(path)
        assert (info.width, info.height) == (64, 32)
        assert info.stats["max_luminance"] == pytest.approx(2.0, rel=0.02)
        assert read_hdr(path).shape == (32, 64, 3)


def test_ringing_slightly_below_zero_is_accepted(tmp_path: Path) -> None:
    """Lossy EXR compression rings a little below 0 near dark pixels (Blender's bundled HDRIs do): a
    few values down to 0.5% of the bright end (99th-percentile luminance) are kept (renders clamp
    them); 5% of it is refused."""
    ringing = sky()  # 99th percentile about 2
    ringing[-1, :4] = -0.01
    info = validate_envmap(write_exr(tmp_path / "r.exr", ringing))
    assert info.stats["min_radiance"] < 0
    ringing[-1, :4] = -0.1
    with pytest.raises(BadEnvmapError, match="negative radiance"):
        validate_envmap(write_exr(tmp_path / "s.exr", ringing))


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda p: write_exr(p.with_suffix(".exr"), np.where(sky() > 1, np.nan, sky())), "non-finite"),
        (lambda p: write_exr(p.with_suffix(".exr"), sky() - 1.0), "negative"),
        (lambda p: write_exr(p.with_suffix(".exr"), np.zeros((32, 64, 3), np.float32)), "all black"),
        (lambda p: write_hdr(p, sky(64, 64)), "not 2:1"),
        (lambda p: write_hdr(p, sky(8, 4)), "too small"),
    ],
    ids=["nan", "negative", "black", "aspect", "tiny"],
)
def test_invalid_maps(tmp_path: Path, make, reason: str) -> None:  # type: ignore[no-untyped-def]
    path = make(tmp_path / "x.hdr")
    with pytest.raises(BadEnvmapError, match=reason):
        validate_envmap(path)


def test_truncated_and_fake_files(tmp_path: Path) -> None:
    good = write_exr(tmp_path / "g.exr", sky()).read_bytes()
    cut = tmp_path / "cut.exr"
    cut.write_bytes(good[: len(good) // 3])
    with pytest.raises(BadEnvmapError, match="unreadable|truncated"):
        validate_envmap(cut)
    fake = tmp_path / "fake.hdr"
    fake.write_bytes(b"this is not radiance")
    with pytest.raises(BadEnvmapError, match="bad magic"):
        validate_envmap(fake)
    bomb = tmp_path / "bomb.hdr"
    bomb.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 200000\n")
    with pytest.raises(BadEnvmapError, match="exceeds the limit"):
        validate_envmap(bomb)


@pytest.mark.realdata
def test_real_envmaps(shared_data: Path) -> None:
    for path in sorted((shared_data / "envmaps").glob("*.hdr")):
        info = validate_envmap(path)
        assert (info.width, info.height) == (1024, 512)
        assert info.stats["max_luminance"] > info.stats["mean_luminance"] > 0
