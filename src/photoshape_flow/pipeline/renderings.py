"""Keep a rendering: its images go to the blob store, then one `Rendering` row points at them.

Encoding by array type, so a pass always comes back as it was rendered:

- uint8 (H, W[, 3|4]) -> PNG (display images, masks);
- uint16 (H, W) -> 16-bit PNG (part-ID and material-ID maps: exact integers, lossless);
- bool (H, W) -> 8-bit PNG of 0/255 (silhouettes; they load back as uint8 0/255: test ``> 127``);
- float16/32/64 -> half-float OpenEXR (HDR radiance, depth, normals);
- bytes -> stored as they are, the extension sniffed from the file signature (PNG, JPEG, WebP, EXR,
  Radiance HDR).

The row is upserted on its natural key (kind, key): recording the same rendering again rewrites the
same row with the same content-addressed refs, so a retried task is harmless.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from photoshape_flow.db.models import Rendering
from photoshape_flow.db.upsert import upsert
from photoshape_flow.faults import fault_point
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import RENDERING_KINDS

log = logging.getLogger(__name__)

_SIGNATURES: tuple[tuple[bytes, str], ...] = (
    (b"\x89PNG\r\n\x1a\n", "png"),
    (b"\xff\xd8\xff", "jpg"),
    (b"\x76\x2f\x31\x01", "exr"),
    (b"#?RADIANCE", "hdr"),
    (b"#?RGBE", "hdr"),
)


def sniff_extension(data: bytes) -> str:
    """File extension of encoded image bytes, from their signature."""
    for signature, ext in _SIGNATURES:
        if data.startswith(signature):
            return ext
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "webp"
    raise ValueError(f"unrecognised image bytes (starting {data[:8]!r}); pass PNG, JPEG, WebP, EXR or HDR")


def store_image(store: BlobStore, image: np.ndarray | bytes) -> str:
    """Store one pass with the encoding its type calls for (see the module docstring); returns the ref."""
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        return store.put_bytes(data, sniff_extension(data))
    array = np.asarray(image)
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (1, 3, 4)):
        raise ValueError(f"image must be (H, W), (H, W, 1|3|4); got shape {array.shape}")
    if array.dtype == np.bool_:
        return store.put_image(array.astype(np.uint8) * 255, "png")
    if array.dtype in (np.uint8, np.uint16):
        return store.put_image(array, "png")
    if np.issubdtype(array.dtype, np.floating):
        return store.put_image(array.astype(np.float32), "exr")
    raise ValueError(f"unsupported image dtype {array.dtype}; use uint8, uint16, bool or float")


def record_rendering(
    session: Session,
    store: BlobStore,
    *,
    kind: str,
    key: str,
    images: Mapping[str, np.ndarray | bytes],
    params: Mapping[str, Any],
    shape_id: int | None = None,
    pair_id: int | None = None,
    material_id: int | None = None,
    envmap_id: int | None = None,
    classifier_id: int | None = None,
    split: str | None = None,
    seconds: float | None = None,
    saturated_fraction: float | None = None,
    params_hash: str = "",
    status: str = "ok",
    error: str | None = None,
) -> int:
    """Store each pass, then upsert the Rendering row on (kind, key); returns its id. Idempotent.

    ``blobs`` maps pass name -> ref. An empty `images` records a row without passes (e.g. a failure
    with ``status="failed"`` and ``error``). The caller's session commits; blobs are durable first.
    """
    if kind not in RENDERING_KINDS:
        raise ValueError(f"unknown rendering kind {kind!r}; expected one of {', '.join(RENDERING_KINDS)}")
    blobs: dict[str, str] = {}
    for name, image in images.items():
        try:
            blobs[name] = store_image(store, image)
        except ValueError as exc:
            raise ValueError(f"rendering {kind}/{key}, pass {name!r}: {exc}") from exc
    if blobs:
        fault_point("rendering-blobs-before-row")
    row = {
        "kind": kind,
        "key": key,
        "shape_id": shape_id,
        "pair_id": pair_id,
        "material_id": material_id,
        "envmap_id": envmap_id,
        "classifier_id": classifier_id,
        "split": split,
        "params": dict(params),
        "blobs": blobs,
        "seconds": seconds,
        "saturated_fraction": saturated_fraction,
        "params_hash": params_hash,
        "status": status,
        "error": error,
    }
    (rendering_id,) = upsert(session, Rendering, row, key=["kind", "key"])
    log.debug("recorded rendering %s/%s (%d passes) as id %d", kind, key, len(images), rendering_id)
    return int(rendering_id)


def load_rendering_image(store: BlobStore, rendering: Rendering, pass_name: str) -> np.ndarray:
    """One pass of a recorded rendering as an array (RGB order; uint16 for ID maps; float32 for EXR)."""
    blobs = rendering.blobs or {}
    if pass_name not in blobs:
        known = ", ".join(sorted(blobs)) or "none"
        raise KeyError(f"rendering {rendering.kind}/{rendering.key} has no pass {pass_name!r} (has: {known})")
    return store.load_image(blobs[pass_name])
