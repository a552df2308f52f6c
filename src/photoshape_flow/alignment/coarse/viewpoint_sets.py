"""Viewpoint sets: the named, versioned, immutable camera sweeps that view features are rendered at.

A shape's view feature and an exemplar's feature are valid for one set of cameras and descriptor
settings; the hashes here tie the stored shards to exactly those inputs.
"""

from __future__ import annotations

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.viewpoints import NAMED_VIEWPOINT_SETS, ViewpointParams, viewpoint_array
from photoshape_flow.alignment.coarse.config import CoarseConfig
from photoshape_flow.db import models as m
from photoshape_flow.db.upsert import upsert
from photoshape_flow.hashing import stable_hash


def ensure_viewpoint_set(
    session: Session, name: str = "paper-456", version: int = 1, params: ViewpointParams | None = None
) -> m.ViewpointSet:
    """The `ViewpointSet` row (name, version), created from `params` (default: the named set's).

    A set is immutable: asking for an existing (name, version) with other cameras is an error, so a
    changed sweep needs a new version and both can coexist.
    """
    if params is None:
        if name not in NAMED_VIEWPOINT_SETS:
            raise ValueError(f"unknown viewpoint set {name!r}: pass params (known: {sorted(NAMED_VIEWPOINT_SETS)})")
        params = NAMED_VIEWPOINT_SETS[name]
    cameras = viewpoint_array(params)
    existing = session.execute(_select(name, version)).scalar_one_or_none()
    if existing is not None:
        stored = np.asarray(existing.cameras, np.float64)
        if stored.shape != cameras.shape or not np.allclose(stored, cameras, atol=1e-9):
            raise ValueError(
                f"viewpoint set {name} v{version} exists with other cameras ({stored.shape[0]} views); "
                "use a new version"
            )
        return existing
    upsert(
        session,
        m.ViewpointSet,
        {
            "name": name,
            "version": version,
            "num_views": int(len(cameras)),
            "cameras": cameras.tolist(),
            "params": params.to_dict(),
        },
        key=["name", "version"],
        update=[],
    )
    return session.execute(_select(name, version)).scalar_one()


def _select(name: str, version: int) -> sa.Select[tuple[m.ViewpointSet]]:
    return sa.select(m.ViewpointSet).where(m.ViewpointSet.name == name, m.ViewpointSet.version == version)


def config_viewpoint_set(session: Session, config: CoarseConfig) -> m.ViewpointSet:
    """The viewpoint set a configuration names (created on first use)."""
    return ensure_viewpoint_set(session, config.viewpoint_set, config.viewpoint_version, config.viewpoint_params)


def cameras_hash(vpset: m.ViewpointSet) -> str:
    """Hash of a set's cameras (rounded to 1e-9, so float noise in storage does not change it)."""
    return stable_hash(np.round(np.asarray(vpset.cameras, np.float64), 9).tolist())


def view_feature_hash(config: CoarseConfig, vpset: m.ViewpointSet, mesh_blob: str | None) -> str:
    """params_hash of a shape's `ViewFeature`: descriptor settings, mesh and cameras."""
    return config.hog.params_hash(mesh=mesh_blob, viewpoints=cameras_hash(vpset))


def exemplar_feature_hash(config: CoarseConfig, image_blob: str | None, mask_blob: str | None) -> str:
    """params_hash of an `ExemplarFeature`: descriptor settings, crop and mask."""
    return config.hog.params_hash(image=image_blob, mask=mask_blob)
