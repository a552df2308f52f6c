"""Validation renders made to look like exemplars: the sample, the exemplars' size, the degradation.

Both calibrations that read photo-like validation renders use these: the BatchNorm priors
(`recognition.bn_prior`, chosen by the substances and training stages) and the fit's weights
(`fitting.calibration`). They sit below both, so neither stage imports the other's code.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.demo.exemplars import degrade, encode_jpeg, sample_degradation
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
