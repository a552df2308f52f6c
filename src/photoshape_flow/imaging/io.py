"""Defensive image reading: format whitelist, pixel and byte limits checked before decoding.

The header is read first (PIL opens lazily), so a decompression bomb (a tiny file declaring a huge
canvas) is refused before any pixel is decoded; truncated and corrupt files become `BadImageError`
with a one-line reason instead of a decoder exception deep in a batch.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np


class BadImageError(ValueError):
    """The file is not a usable image (not an image, corrupt, truncated, too large, blank)."""


DEFAULT_MAX_PIXELS = 64_000_000
DEFAULT_MAX_BYTES = 256 * 1024 * 1024


def _check_bytes(path: Path, max_bytes: int) -> None:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise BadImageError(f"unreadable ({exc.strerror or exc})") from exc
    if size == 0:
        raise BadImageError("empty file")
    if size > max_bytes:
        raise BadImageError(f"file is {size} bytes (limit {max_bytes})")


def aspect_refusal(width: int, height: int, max_aspect: float | None) -> str | None:
    """Why a `width` x `height` canvas is too elongated (None when it is not, or no limit is set).

    A 240-byte 80000x2 PNG has few pixels, but anything squaring its long side (an exemplar's
    crop) would need 80000^2; such strips are no photo of an object, so they are refused unread.
    """
    if max_aspect is None:
        return None
    ratio = max(width, height) / max(min(width, height), 1)
    if ratio <= max_aspect:
        return None
    return f"{width}x{height} pixels: aspect ratio {ratio:.0f}:1 exceeds the limit of {max_aspect:g}:1"


def read_image(
    path: str | Path,
    *,
    formats: tuple[str, ...] | None = ("JPEG", "PNG", "WEBP"),
    max_pixels: int = DEFAULT_MAX_PIXELS,
    max_bytes: int = DEFAULT_MAX_BYTES,
    mode: str = "RGB",
    background: tuple[int, int, int] = (255, 255, 255),
    max_aspect: float | None = None,
) -> tuple[np.ndarray, dict[str, object]]:
    """Decode an image as RGB uint8 (alpha composited over `background`) or keep 8/16-bit data.

    `mode`: "RGB" -> (H, W, 3) uint8 with EXIF orientation applied; "raw" -> the decoded array in
    its own depth (uint8/uint16, 1 or 3 channels, alpha dropped). Returns (array, info) where info
    holds format, native size and whether the source had alpha. `max_aspect`: the longest side
    may be at most this many times the shortest (checked from the header, before decoding).
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    path = Path(path)
    _check_bytes(path, max_bytes)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(path)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise BadImageError(f"decompression bomb refused ({exc})") from exc
    except UnidentifiedImageError as exc:
        raise BadImageError("not an image (unrecognised format)") from exc
    except OSError as exc:
        raise BadImageError(f"unreadable ({exc})") from exc
    with image:
        fmt = image.format or "?"
        if formats is not None and fmt not in formats:
            raise BadImageError(f"unsupported image format {fmt} (expected {', '.join(formats)})")
        width, height = image.size
        if width <= 0 or height <= 0:
            raise BadImageError(f"empty image ({width}x{height})")
        if width * height > max_pixels:
            raise BadImageError(f"{width}x{height} pixels exceeds the limit of {max_pixels} (decompression bomb?)")
        reason = aspect_refusal(width, height, max_aspect)
        if reason is not None:
            raise BadImageError(reason)
        try:
            image.load()
        except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
            raise BadImageError(f"corrupt or truncated image data ({exc})") from exc
        has_alpha = "A" in image.getbands() or (image.mode == "P" and "transparency" in image.info)
        info: dict[str, object] = {"format": fmt, "width": width, "height": height, "has_alpha": has_alpha}
        if mode == "RGB":
            try:
                image = ImageOps.exif_transpose(image) or image
            except Exception:  # broken EXIF: keep the stored orientation
                pass
            if image.mode in ("I;16", "I;16B", "I;16L", "I"):
                array = np.asarray(image, dtype=np.float64)
                scale = 65535.0 if array.max() > 255 else 255.0
                image = Image.fromarray(np.clip(array / scale * 255.0 + 0.5, 0, 255).astype(np.uint8))
            if has_alpha:
                rgba = image.convert("RGBA")
                canvas = Image.new("RGBA", rgba.size, (*background, 255))
                canvas.alpha_composite(rgba)
                image = canvas
            rgb = np.asarray(image.convert("RGB"), dtype=np.uint8)
            info["width"], info["height"] = rgb.shape[1], rgb.shape[0]
            return np.ascontiguousarray(rgb), info
        array = _raw_array(image)
        return array, info


def _raw_array(image) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The decoded pixels at their own depth: uint8 or uint16, (H, W) or (H, W, 3), no alpha."""
    from PIL import Image

    if image.mode in ("I;16", "I;16B", "I;16L"):
        return np.asarray(image, dtype=np.uint16).copy()
    if image.mode == "I":
        array = np.asarray(image, dtype=np.int64)
        return np.clip(array, 0, 65535).astype(np.uint16)
    if image.mode == "F":
        return np.asarray(image, dtype=np.float32).copy()
    if image.mode in ("L", "1"):
        return np.asarray(image.convert("L"), dtype=np.uint8).copy()
    if image.mode in ("LA",):
        return np.asarray(image.convert("L"), dtype=np.uint8).copy()
    if not isinstance(image, Image.Image):
        raise BadImageError("not an image")
    return np.asarray(image.convert("RGB"), dtype=np.uint8).copy()


def read_map(
    path: str | Path, *, max_pixels: int = DEFAULT_MAX_PIXELS, max_bytes: int = DEFAULT_MAX_BYTES
) -> np.ndarray:
    """A texture map at its own bit depth (uint8/uint16, grey or RGB). 16-bit PNG/TIFF via OpenCV."""
    import cv2

    path = Path(path)
    array, info = read_image(path, formats=None, max_pixels=max_pixels, max_bytes=max_bytes, mode="raw")
    if info["format"] in ("PNG", "TIFF") and array.dtype == np.uint8 and array.ndim == 3:
        # PIL reduces 16-bit RGB PNGs to 8 bits; OpenCV keeps them (size was already checked above)
        decoded = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if decoded is not None and decoded.dtype == np.uint16 and decoded.ndim == 3:
            return np.ascontiguousarray(decoded[..., [2, 1, 0]])
    return array


# The pipeline's own renders and label maps (written by this package, read without the limits above)


def load_rgb(path: Path) -> np.ndarray:
    """An image file as RGB uint8 (H, W, 3); a one-line error naming the file when unreadable."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    return np.ascontiguousarray(image[..., ::-1])


def load_label_map(path: Path) -> np.ndarray:
    """A label map (uint16 PNG or .npy) as an integer (H, W) array."""
    if path.suffix == ".npy":
        array = np.load(path, allow_pickle=False)
    else:
        import cv2

        array = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if array is None:
            raise ValueError(f"{path}: not a readable label map")
    if array.ndim != 2:
        raise ValueError(f"{path}: label map must be single-channel, got shape {array.shape}")
    return array
