"""Equirectangular HDR environment maps (.hdr Radiance RGBE, .exr OpenEXR): read and validate.

The size is read from the file header before decoding, so absurd canvases are refused cheaply.
Decoding: OpenCV for .hdr; Mitsuba's Bitmap for .exr (the pip OpenCV wheel is built without
OpenEXR; Mitsuba's Bitmap needs no variant and no LLVM). A valid map is finite, non-negative, not
black, of sane size and 2:1 aspect (equirectangular).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

HDR_SUFFIXES = {".hdr", ".exr"}


class BadEnvmapError(ValueError):
    """Not a usable environment map."""


@dataclass(frozen=True)
class EnvmapLimits:
    min_width: int = 16
    max_pixels: int = 8192 * 4096 * 2
    max_bytes: int = 1024 * 1024 * 1024
    aspect: float = 2.0
    aspect_tolerance: float = 0.02  # relative
    # negative radiance is accepted down to this fraction of the map's 99th-percentile luminance (its
    # bright end, which lights a scene) or `negative_floor`, whichever is lower: lossy EXR compression
    # and resampling ring slightly below 0 near dark pixels (Blender's bundled HDRIs reach -0.5% of it),
    # and renders clamp at 0; anything deeper is a wrongly encoded map
    negative_tolerance: float = 0.01
    negative_floor: float = 1e-6  # absolute: a map whose 99th percentile is black (a lone sun) keeps it
    # the brightest real suns in HDRIs reach about 1e5-1e6; RGBE can encode 1.7e38, whose luminance
    # (a weighted sum) overflows float32 to infinity: anything past this is no photograph of a sky
    max_radiance: float = 1e9


@dataclass
class EnvmapInfo:
    width: int
    height: int
    stats: dict[str, Any] = field(default_factory=dict)


def _hdr_size(head: bytes) -> tuple[int, int]:
    if not (head.startswith(b"#?RADIANCE") or head.startswith(b"#?RGBE")):
        raise BadEnvmapError("not a Radiance HDR file (bad magic)")
    text = head.split(b"\n\n", 1)
    if len(text) < 2:
        raise BadEnvmapError("truncated Radiance header")
    resolution = text[1].split(b"\n", 1)[0].decode("ascii", errors="replace").strip()
    match = re.match(r"^([-+])Y\s+(\d+)\s+([-+])X\s+(\d+)$", resolution)
    if not match:
        raise BadEnvmapError(f"unsupported Radiance resolution line {resolution!r}")
    return int(match.group(4)), int(match.group(2))


def _exr_size(head: bytes) -> tuple[int, int]:
    if head[:4] != b"\x76\x2f\x31\x01":
        raise BadEnvmapError("not an OpenEXR file (bad magic)")
    pos = 8
    while pos < len(head):
        end = head.find(b"\0", pos)
        if end < 0:
            break
        name = head[pos:end]
        if not name:
            break
        type_end = head.find(b"\0", end + 1)
        if type_end < 0 or type_end + 4 > len(head):
            break
        (size,) = struct.unpack("<i", head[type_end + 1 : type_end + 5])
        value = head[type_end + 5 : type_end + 5 + size]
        if name == b"dataWindow" and len(value) == 16:
            x0, y0, x1, y1 = struct.unpack("<4i", value)
            return x1 - x0 + 1, y1 - y0 + 1
        pos = type_end + 5 + size
    raise BadEnvmapError("OpenEXR header has no dataWindow (truncated or corrupt)")


def header_size(path: Path) -> tuple[int, int]:
    """(width, height) from the header of a .hdr or .exr file."""
    with open(path, "rb") as handle:
        head = handle.read(65536)
    if not head:
        raise BadEnvmapError("empty file")
    suffix = path.suffix.lower()
    if suffix == ".hdr":
        return _hdr_size(head)
    if suffix == ".exr":
        return _exr_size(head)
    raise BadEnvmapError(f"unsupported environment map format {suffix!r} (expected .hdr or .exr)")


def read_hdr(path: Path) -> np.ndarray:
    """(H, W, 3) float32 linear RGB."""
    path = Path(path)
    if path.suffix.lower() == ".exr":
        import mitsuba as mi

        try:
            array = np.array(mi.Bitmap(str(path)), dtype=np.float32)
        except Exception as exc:  # Mitsuba raises RuntimeError subclasses on corrupt files
            raise BadEnvmapError(f"unreadable OpenEXR data ({str(exc).splitlines()[0][:200]})") from exc
    else:
        import cv2

        data = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
        if data is None:
            raise BadEnvmapError("unreadable Radiance HDR data (corrupt or truncated)")
        array = data.astype(np.float32)
        if array.ndim == 3:
            array = array[..., ::-1]
    if array.ndim == 2:
        array = array[..., None]
    if array.shape[2] == 1:
        array = np.repeat(array, 3, axis=2)
    return np.ascontiguousarray(array[..., :3], dtype=np.float32)


def validate_envmap(path: Path, limits: EnvmapLimits | None = None) -> EnvmapInfo:
    """Check header, decode and check values; BadEnvmapError with the reason otherwise."""
    limits = limits or EnvmapLimits()
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise BadEnvmapError(f"unreadable ({exc.strerror or exc})") from exc
    if size > limits.max_bytes:
        raise BadEnvmapError(f"file is {size} bytes (limit {limits.max_bytes})")
    try:
        width, height = header_size(path)
    except OSError as exc:
        raise BadEnvmapError(f"unreadable ({exc})") from exc
    if width < limits.min_width or height < 1:
        raise BadEnvmapError(f"too small ({width}x{height})")
    if width * height > limits.max_pixels:
        raise BadEnvmapError(f"{width}x{height} exceeds the limit of {limits.max_pixels} pixels")
    ratio = width / height
    if abs(ratio - limits.aspect) > limits.aspect_tolerance * limits.aspect:
        raise BadEnvmapError(f"aspect {width}x{height} is not 2:1 (equirectangular expected)")
    array = read_hdr(path)
    if array.shape[0] != height or array.shape[1] != width:
        raise BadEnvmapError(f"decoded size {array.shape[1]}x{array.shape[0]} differs from the header")
    if not np.isfinite(array).all():
        raise BadEnvmapError(f"{int((~np.isfinite(array)).sum())} non-finite (NaN/inf) values")
    high = float(array.max())
    if high > limits.max_radiance:
        raise BadEnvmapError(f"radiance up to {high:.3g}, beyond the limit of {limits.max_radiance:.0e} "
                             "(absurd values; a sun is about 1e5)")
    low = float(array.min())
    luminance = array @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    peak = float(luminance.max())
    if peak <= 0:
        raise BadEnvmapError("all black")
    p99 = float(np.percentile(luminance, 99))
    if low < -max(limits.negative_tolerance * p99, limits.negative_floor):
        raise BadEnvmapError(f"negative radiance (minimum {low:.3g}, beyond {limits.negative_tolerance:.0%} of "
                             f"the 99th-percentile luminance {p99:.3g})")
    stats = {
        "min_radiance": low,  # clamped to 0 when rendered
        "mean_luminance": float(luminance.mean()),
        "max_luminance": peak,
        "p99_luminance": p99,
    }
    return EnvmapInfo(width=width, height=height, stats=stats)
