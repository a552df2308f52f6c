"""Defensive image decoding: non-images, truncation, bombs, alpha and depth."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from photoshape_flow.imaging.io import BadImageError, read_image, read_map


def _jpeg(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, "JPEG", quality=90)
    return buffer.getvalue()


def png_declaring(width: int, height: int) -> bytes:
    """A tiny PNG whose header declares a huge canvas (a decompression bomb)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"", "empty file"),
        (b"hello, not an image", "not an image"),
        (png_declaring(100_000, 100_000), "decompression bomb|exceeds the limit"),
        (png_declaring(9000, 9000), "exceeds the limit"),
    ],
    ids=["empty", "text", "bomb", "over-limit"],
)
def test_bad_files(tmp_path: Path, content: bytes, reason: str) -> None:
    path = tmp_path / "x.png"
    path.write_bytes(content)
    with pytest.raises(BadImageError, match=reason):
        read_image(path, max_pixels=50_000_000)


def test_truncated_jpeg(tmp_path: Path) -> None:
    data = _jpeg(np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8))
    path = tmp_path / "cut.jpg"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(BadImageError, match="truncated|corrupt"):
        read_image(path)


def test_unsupported_format_and_size_limit(tmp_path: Path) -> None:
    path = tmp_path / "x.bmp"
    Image.new("RGB", (4, 4)).save(path)
    with pytest.raises(BadImageError, match="unsupported image format BMP"):
        read_image(path)
    big = tmp_path / "big.png"
    Image.new("RGB", (100, 100)).save(big)
    with pytest.raises(BadImageError, match="bytes \\(limit"):
        read_image(big, max_bytes=10)


def test_alpha_is_composited_on_white(tmp_path: Path) -> None:
    rgba = np.zeros((4, 4, 4), np.uint8)
    rgba[0, 0] = (255, 0, 0, 255)
    path = tmp_path / "a.png"
    Image.fromarray(rgba).save(path)
    rgb, info = read_image(path)
    assert info["has_alpha"] and rgb.shape == (4, 4, 3)
    assert tuple(rgb[0, 0]) == (255, 0, 0) and tuple(rgb[3, 3]) == (255, 255, 255)


def test_maps_keep_16_bits(tmp_path: Path) -> None:
    import cv2

    grey = (np.arange(16, dtype=np.uint16) * 4000).reshape(4, 4)
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    rgb16 = np.dstack([grey, grey // 2, grey // 3]).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "c.png"), rgb16[..., ::-1])
    assert read_map(tmp_path / "g.png").dtype == np.uint16
    loaded = read_map(tmp_path / "c.png")
    assert loaded.dtype == np.uint16 and np.array_equal(loaded, rgb16)
