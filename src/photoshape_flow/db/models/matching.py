"""Shape-photo matching (section 4): viewpoint sweeps and their descriptors, the coarse-alignment
reverse index, the shape-exemplar pairs it yields and their fine alignments."""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column

from photoshape_flow.db.base import (
    Base,
    ExcludeMixin,
    ParamsHashMixin,
    StatusMixin,
    TimestampMixin,
    fk,
)


class ViewpointSet(TimestampMixin, Base):
    """A named, versioned list of cameras for coarse alignment (several may coexist)."""

    __tablename__ = "viewpoint_set"
    __table_args__ = (sa.UniqueConstraint("name", "version"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(sa.String(64))
    version: Mapped[int] = mapped_column(default=1)
    num_views: Mapped[int]
    cameras: Mapped[list[Any]] = mapped_column(
        comment="[[azimuth, elevation, distance, fov_deg], ...] in radians except fov"
    )
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)


class ViewFeature(TimestampMixin, StatusMixin, ParamsHashMixin, Base):
    """Descriptors of one shape's viewpoint sweep: one float16 shard (num_views x dims) per row."""

    __tablename__ = "view_feature"
    __table_args__ = (sa.UniqueConstraint("shape_id", "viewpoint_set_id", "descriptor"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    shape_id: Mapped[int] = mapped_column(fk("shape.id"), index=True)
    viewpoint_set_id: Mapped[int] = mapped_column(fk("viewpoint_set.id"), index=True)
    descriptor: Mapped[str] = mapped_column(sa.String(64))
    feature_blob: Mapped[str | None] = mapped_column(sa.String(80))
    dims: Mapped[int | None]
    num_views: Mapped[int | None]
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)


class ExemplarFeature(TimestampMixin, StatusMixin, ParamsHashMixin, Base):
    """A descriptor of one exemplar (HOG for retrieval, dense HOG for dedupe)."""

    __tablename__ = "exemplar_feature"
    __table_args__ = (sa.UniqueConstraint("exemplar_id", "descriptor"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    exemplar_id: Mapped[int] = mapped_column(fk("exemplar.id"), index=True)
    descriptor: Mapped[str] = mapped_column(sa.String(64))
    feature_blob: Mapped[str | None] = mapped_column(sa.String(80))
    dims: Mapped[int | None]


class ExemplarMatch(TimestampMixin, ParamsHashMixin, Base):
    """One entry of the coarse-alignment reverse index (section 4.1): a shape, its best view, ranked.

    Per exemplar, viewpoint set, descriptor and scope (category restriction, '' for none) the stage
    keeps the top-k shapes by exact search; `searched_at` is when that list was last searched, so a
    later run searches the exemplar only against shapes whose features appeared or changed since.
    """

    __tablename__ = "exemplar_match"
    # named by hand: the convention's name (69 characters) is past PostgreSQL's 63, where it would
    # be shortened differently than on SQLite
    __table_args__ = (
        sa.UniqueConstraint(
            "exemplar_id", "viewpoint_set_id", "descriptor", "scope", "rank",
            name="uq_exemplar_match__exemplar_id_vpset_descriptor_scope_rank",
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    exemplar_id: Mapped[int] = mapped_column(fk("exemplar.id"))
    viewpoint_set_id: Mapped[int] = mapped_column(fk("viewpoint_set.id"))
    descriptor: Mapped[str] = mapped_column(sa.String(64), comment="descriptor name, e.g. hog-insensitive9")
    scope: Mapped[str] = mapped_column(
        sa.String(64), default="", server_default="", comment="category the search was restricted to, or ''"
    )
    rank: Mapped[int] = mapped_column(comment="rank of the shape among the exemplar's matches (1 = best)")
    shape_id: Mapped[int] = mapped_column(fk("shape.id"), index=True)
    view_index: Mapped[int] = mapped_column(comment="index of the shape's best view in the viewpoint set")
    distance: Mapped[float] = mapped_column(comment="squared L2 distance of the descriptors")
    searched_at: Mapped[dt.datetime] = mapped_column(comment="when this exemplar's list was last searched")


class Pair(TimestampMixin, ExcludeMixin, ParamsHashMixin, Base):
    """A shape-exemplar candidate from coarse alignment, with the retrieved camera."""

    __tablename__ = "pair"
    __table_args__ = (sa.UniqueConstraint("shape_id", "exemplar_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    shape_id: Mapped[int] = mapped_column(fk("shape.id"), index=True)
    exemplar_id: Mapped[int] = mapped_column(fk("exemplar.id"), index=True)
    viewpoint_set_id: Mapped[int | None] = mapped_column(fk("viewpoint_set.id", "SET NULL"))
    descriptor: Mapped[str | None] = mapped_column(sa.String(64))
    view_index: Mapped[int | None]
    rank: Mapped[int] = mapped_column(comment="rank of the exemplar among this shape's exemplars (1 = best)")
    exemplar_rank: Mapped[int | None] = mapped_column(comment="rank of the shape among the exemplar's matches")
    distance: Mapped[float]
    azimuth: Mapped[float]
    elevation: Mapped[float]
    fov: Mapped[float] = mapped_column(comment="horizontal field of view, degrees")
    camera_distance: Mapped[float]
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Alignment(TimestampMixin, StatusMixin, ParamsHashMixin, Base):
    """Fine alignment of a pair: coarse, flow-warped and CRF part maps plus their quality."""

    __tablename__ = "alignment"
    __table_args__ = (sa.UniqueConstraint("pair_id", "method"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(fk("pair.id"), index=True)
    method: Mapped[str] = mapped_column(sa.String(64), default="flow-crf")
    coarse_blob: Mapped[str | None] = mapped_column(sa.String(80))
    flow_blob: Mapped[str | None] = mapped_column(sa.String(80))
    crf_blob: Mapped[str | None] = mapped_column(sa.String(80))
    iou_coarse: Mapped[float | None]
    iou_flow: Mapped[float | None]
    iou_crf: Mapped[float | None]
    accuracy_coarse: Mapped[float | None] = mapped_column(comment="part-label pixel accuracy vs demo ground truth")
    accuracy_flow: Mapped[float | None]
    accuracy_crf: Mapped[float | None]
    seconds: Mapped[float | None]
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)
