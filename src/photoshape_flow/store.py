"""Content-addressed blob store for every file the pipeline writes.

A blob is named by the sha256 of its bytes plus an extension (``<sha256>.<ext>``); that name is the
*ref* stored in database rows. Files live under ``<root>/<aa>/<bb>/<ref>``. Writes go to a temporary
file in the same folder, are fsynced, then renamed into place, so a ref that exists is always
complete; a second write of the same bytes is a no-op (dedupe). Rows are committed only after their
blobs are written, so a row never points at a missing or half-written file. ``gc`` removes blobs no
row references, sparing young ones that may belong to a transaction still in flight.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import tempfile
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REF_PATTERN = re.compile(r"^[0-9a-f]{64}\.[a-z0-9]{1,8}$")


class BlobNotFoundError(FileNotFoundError):
    """A ref names a blob that is not in the store."""


def is_ref(value: object) -> bool:
    """True when `value` looks like a blob ref."""
    return isinstance(value, str) and REF_PATTERN.match(value) is not None


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Streaming sha256 of a file (used for provenance of ingested sources)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def _mitsuba():  # type: ignore[no-untyped-def]
    """Mitsuba's Bitmap reads/writes OpenEXR (the pip OpenCV wheels are built without it)."""
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")  # any variant has Bitmap; the renderer switches to its own later
    return mi


def _encode_exr(array: np.ndarray) -> bytes:
    """Half-float OpenEXR bytes of an (H, W[, C]) float image."""
    mi = _mitsuba()
    stream = mi.MemoryStream()
    mi.Bitmap(np.ascontiguousarray(array, dtype=np.float16)).write(stream, mi.Bitmap.FileFormat.OpenEXR)
    stream.seek(0)
    return bytes(stream.read(stream.size()))


def _decode_exr(path: Path) -> np.ndarray:
    mi = _mitsuba()
    return np.array(mi.Bitmap(str(path)), dtype=np.float32)


@dataclass(frozen=True)
class GcReport:
    scanned: int
    removed: int
    kept_young: int
    freed_bytes: int


class BlobStore:
    """A folder of immutable, content-named files."""

    def __init__(self, root: str | os.PathLike[str]):
        self.root = Path(root)

    # -- paths -----------------------------------------------------------------------------
    def path(self, ref: str) -> Path:
        """Where the blob named `ref` lives (whether or not it exists)."""
        if not is_ref(ref):
            raise ValueError(f"not a blob ref: {ref!r}")
        return self.root / ref[:2] / ref[2:4] / ref

    def exists(self, ref: str) -> bool:
        return self.path(ref).is_file()

    def resolve(self, ref: str) -> Path:
        """Path of an existing blob; a clear error when it is missing."""
        path = self.path(ref)
        if not path.is_file():
            raise BlobNotFoundError(f"{path}: blob {ref} is missing from the store")
        return path

    # -- writing ---------------------------------------------------------------------------
    def put_bytes(self, data: bytes, ext: str) -> str:
        """Store `data`; returns its ref. Idempotent and atomic."""
        ext = ext.lower().lstrip(".")
        ref = f"{sha256_bytes(data)}.{ext}"
        target = self.path(ref)
        if target.is_file() and target.stat().st_size == len(data):
            return ref
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=target.parent)
        try:
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return ref

    def put_file(self, path: str | os.PathLike[str], ext: str | None = None) -> str:
        """Copy a file into the store (extension from the file name unless given)."""
        source = Path(path)
        return self.put_bytes(source.read_bytes(), ext or source.suffix.lstrip(".") or "bin")

    def put_array(self, array: np.ndarray) -> str:
        """Store a numpy array as .npy (dtype and shape preserved)."""
        buffer = io.BytesIO()
        np.save(buffer, np.ascontiguousarray(array), allow_pickle=False)
        return self.put_bytes(buffer.getvalue(), "npy")

    def put_image(self, image: np.ndarray, ext: str = "png", quality: int = 95) -> str:
        """Store an 8- or 16-bit image (H, W[, C]) as PNG/JPEG/WebP, or a float image as half-float .exr or .hdr."""
        import cv2

        ext = ext.lower().lstrip(".")
        array = np.asarray(image)
        if array.ndim == 3 and array.shape[2] >= 3:
            channels = array[..., [2, 1, 0, *range(3, array.shape[2])]]  # RGB(A) -> BGR(A)
        else:
            channels = array
        params: list[int] = []
        if ext in ("jpg", "jpeg"):
            params = [cv2.IMWRITE_JPEG_QUALITY, quality]
        elif ext == "webp":
            params = [cv2.IMWRITE_WEBP_QUALITY, quality]
        elif ext == "exr":
            return self.put_bytes(_encode_exr(array), "exr")
        elif ext == "hdr":
            channels = channels.astype(np.float32)
        ok, encoded = cv2.imencode(f".{ext}", np.ascontiguousarray(channels), params)
        if not ok:
            raise ValueError(f"could not encode image of shape {array.shape} as {ext}")
        return self.put_bytes(encoded.tobytes(), ext)

    def put_json(self, payload: Any) -> str:
        data = json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()
        return self.put_bytes(data, "json")

    # -- reading ---------------------------------------------------------------------------
    def read_bytes(self, ref: str) -> bytes:
        return self.resolve(ref).read_bytes()

    def load_array(self, ref: str) -> np.ndarray:
        return np.load(self.resolve(ref), allow_pickle=False)

    def load_image(self, ref: str, flags: int | None = None) -> np.ndarray:
        """Load an image blob as RGB(A) (uint8/uint16) or float32 for HDR/EXR."""
        import cv2

        path = self.resolve(ref)
        if path.suffix == ".exr":
            return _decode_exr(path)
        if flags is None:
            flags = cv2.IMREAD_UNCHANGED
            if path.suffix == ".hdr":
                flags = cv2.IMREAD_ANYCOLOR | cv2.IMREAD_ANYDEPTH
        image = cv2.imread(str(path), flags)
        if image is None:
            raise ValueError(f"{path}: not a readable image")
        if image.ndim == 3 and image.shape[2] >= 3:
            image = image[..., [2, 1, 0, *range(3, image.shape[2])]]
        return np.ascontiguousarray(image)

    def load_json(self, ref: str) -> Any:
        return json.loads(self.read_bytes(ref))

    # -- maintenance -----------------------------------------------------------------------
    def iter_refs(self) -> Iterator[str]:
        if not self.root.is_dir():
            return
        for path in self.root.glob("??/??/*"):
            if is_ref(path.name):
                yield path.name

    def gc(self, referenced: Iterable[str], grace_seconds: float = 3600.0, dry_run: bool = False) -> GcReport:
        """Remove blobs not in `referenced` and older than `grace_seconds`."""
        keep = set(referenced)
        now = time.time()
        scanned = removed = young = freed = 0
        for ref in list(self.iter_refs()):
            scanned += 1
            if ref in keep:
                continue
            path = self.path(ref)
            stat = path.stat()
            if now - stat.st_mtime < grace_seconds:
                young += 1
                continue
            removed += 1
            freed += stat.st_size
            if not dry_run:
                path.unlink(missing_ok=True)
        # stale temporary files of crashed writers
        if not dry_run and self.root.is_dir():
            for tmp in self.root.glob("??/??/.tmp-*"):
                if now - tmp.stat().st_mtime > grace_seconds:
                    tmp.unlink(missing_ok=True)
        return GcReport(scanned=scanned, removed=removed, kept_young=young, freed_bytes=freed)
