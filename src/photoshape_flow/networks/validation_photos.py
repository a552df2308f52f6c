"""Validation renders made to look like exemplars: the sample, the exemplars' size, the degradation.

The calibrations that read photo-like validation renders use these: the BatchNorm priors
(`recognition.bn_prior`, chosen by the substances and training stages), the colour likelihood's
sigma (`recognition.calibration`) and the fit's weights (`fitting.calibration`); the last two see
the same photo (`calibration_photo`). They sit below every stage, so no stage imports another's code.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.demo.exemplars import degrade, encode_jpeg, sample_degradation
from photoshape_flow.fit.validation import frame, misalign, resampled, sample_misalignment
from photoshape_flow.hashing import item_seed
from photoshape_flow.vocab import STATUS_OK

KINDS = ("training", "bootstrap")  # both rounds' val renders: val shapes under val envmaps


def validation_renders(session: sa.orm.Session, count: int, seed: int,
                       kinds: Sequence[str] = KINDS) -> list[m.Rendering]:
    """Up to `count` ok, non-excluded validation renders of `kinds`, a deterministic sample by seed and key."""
    rows = session.execute(
        sa.select(m.Rendering).where(m.Rendering.kind.in_(list(kinds)), m.Rendering.split == "val",
                                     m.Rendering.status == STATUS_OK, m.Rendering.exclude.is_(False))
    ).scalars().all()
    rows = [r for r in rows if {"hdr", "part_ids"} <= set(r.blobs or {}) and r.shape_id is not None]
    rows.sort(key=lambda r: (item_seed(seed, "fit-calibration", r.kind, r.key), r.id))
    return rows[: max(0, count)]


def exemplar_size(session: sa.orm.Session) -> int | None:
    """The median side of the stored exemplar crops (None: no exemplar stored yet)."""
    sizes = session.execute(sa.select(m.Exemplar.size).where(
        m.Exemplar.status == STATUS_OK, ~m.Exemplar.exclude, m.Exemplar.size.is_not(None))).scalars().all()
    return int(np.median(sizes)) if sizes else None


def as_photo(hdr: np.ndarray, part_ids: np.ndarray, seed: int) -> np.ndarray:
    """A validation render (white-composited linear HDR) degraded like a demo exemplar: 8-bit sRGB after JPEG."""
    covered = (np.asarray(part_ids) > 0).astype(np.float32)
    premultiplied = np.asarray(hdr, np.float32)[..., :3] * covered[..., None]
    params = sample_degradation(np.random.default_rng(seed))
    image = degrade(premultiplied, covered, params)
    decoded = cv2.imdecode(np.frombuffer(encode_jpeg(image, params["jpeg_quality"]), np.uint8), cv2.IMREAD_COLOR)
    return np.ascontiguousarray(decoded[..., ::-1])


def calibration_photo(hdr: np.ndarray, part_ids: np.ndarray, photo_size: int | None, frame_size: int,
                      rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(RGB, part ids, foreground) of a validation render seen as the pipeline sees an exemplar.

    Resampled to `photo_size` (None: the render's own), degraded there (`as_photo`), framed to the
    silhouette's square at `frame_size` (`fit.validation.frame`) and its part map misaligned as fine
    alignment errs (`fit.validation.misalign`); `rng` (seeded by the caller from the render's key)
    draws the degradation, then the misalignment.
    """
    if photo_size:
        hdr, part_ids = resampled(hdr, part_ids, photo_size)
    rgb, labels, foreground = frame(as_photo(hdr, part_ids, int(rng.integers(2**31 - 1))), part_ids, frame_size)
    return rgb, misalign(labels, sample_misalignment(rng, frame_size)), foreground
