"""Bytes <-> arrays, images and JSON, as the store writes and reads them.

Encoding is pure (array in, bytes out) so every backend stores exactly the same bytes and
therefore the same ref; decoding reads a local file, which is what `BlobStore.resolve` returns.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np


def _mitsuba():  # type: ignore[no-untyped-def]
    """Mitsuba's Bitmap reads/writes OpenEXR (the pip OpenCV wheels are built without it)."""
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")  # any variant has Bitmap; the renderer switches to its own later
    return mi


def encode_exr(array: np.ndarray) -> bytes:
    """Half-float OpenEXR bytes of an (H, W[, C]) float image."""
    mi = _mitsuba()
    stream = mi.MemoryStream()
    mi.Bitmap(np.ascontiguousarray(array, dtype=np.float16)).write(stream, mi.Bitmap.FileFormat.OpenEXR)
    stream.seek(0)
    return bytes(stream.read(stream.size()))


def decode_exr(path: Path) -> np.ndarray:
    mi = _mitsuba()
    return np.array(mi.Bitmap(str(path)), dtype=np.float32)


def encode_array(array: np.ndarray) -> bytes:
    """.npy bytes (dtype and shape preserved, no pickles)."""
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(array), allow_pickle=False)
    return buffer.getvalue()


def encode_json(payload: Any) -> bytes:
    """Canonical JSON (sorted keys, no spaces): equal payloads get equal refs."""
    return json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()


def _swap_rgb_bgr(array: np.ndarray) -> np.ndarray:
    """RGB(A) <-> BGR(A) (OpenCV's order); other layouts pass through."""
    if array.ndim == 3 and array.shape[2] >= 3:
        return array[..., [2, 1, 0, *range(3, array.shape[2])]]
    return array


def encode_image(image: np.ndarray, ext: str, quality: int = 95) -> bytes:
    """PNG/JPEG/WebP bytes of an 8- or 16-bit image, half-float .exr or .hdr of a float one."""
    import cv2

    array = np.asarray(image)
    if ext == "exr":
        return encode_exr(array)
    channels = _swap_rgb_bgr(array)
    params: list[int] = []
    if ext in ("jpg", "jpeg"):
        params = [cv2.IMWRITE_JPEG_QUALITY, quality]
    elif ext == "webp":
        params = [cv2.IMWRITE_WEBP_QUALITY, quality]
    elif ext == "hdr":
        channels = channels.astype(np.float32)
    ok, encoded = cv2.imencode(f".{ext}", np.ascontiguousarray(channels), params)
    if not ok:
        raise ValueError(f"could not encode image of shape {array.shape} as {ext}")
    return encoded.tobytes()


def decode_image(path: Path, flags: int | None = None) -> np.ndarray:
    """An image file as RGB(A) (uint8/uint16) or float32 for HDR/EXR."""
    import cv2

    if path.suffix == ".exr":
        return decode_exr(path)
    if flags is None:
        flags = cv2.IMREAD_UNCHANGED
        if path.suffix == ".hdr":
            flags = cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH
    image = cv2.imread(str(path), flags)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return np.ascontiguousarray(_swap_rgb_bgr(image))
