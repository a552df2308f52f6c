"""Material recognition and its products (section 5): per-part substances, renderings, the trained
networks and the materials they assign to parts."""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column

from photoshape_flow.db.base import (
    Base,
    ExcludeMixin,
    ParamsHashMixin,
    Short,
    StatusMixin,
    Str,
    TimestampMixin,
    fk,
)


class PartSubstance(TimestampMixin, ParamsHashMixin, Base):
    """The substance of a part as seen in one pair's exemplar (majority overlap, with confidence)."""

    __tablename__ = "part_substance"
    __table_args__ = (sa.UniqueConstraint("pair_id", "part_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(fk("pair.id"), index=True)
    part_id: Mapped[int] = mapped_column(fk("part.id"), index=True)
    classifier_id: Mapped[int | None] = mapped_column(fk("classifier.id", "SET NULL"))
    observed: Mapped[bool] = mapped_column(default=True, comment="false: the part has no pixels in the exemplar")
    substance: Mapped[str | None] = mapped_column(Short)
    confidence: Mapped[float | None]
    pixel_count: Mapped[int] = mapped_column(default=0)
    probs: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Rendering(TimestampMixin, StatusMixin, ExcludeMixin, ParamsHashMixin, Base):
    """Any image the pipeline renders and keeps, reproducible from `params`."""

    __tablename__ = "rendering"
    __table_args__ = (sa.UniqueConstraint("kind", "key"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(Short, index=True)
    key: Mapped[str] = mapped_column(Str, comment="natural key within the kind (also the seed source)")
    shape_id: Mapped[int | None] = mapped_column(fk("shape.id"), index=True)
    pair_id: Mapped[int | None] = mapped_column(fk("pair.id"), index=True)
    material_id: Mapped[int | None] = mapped_column(fk("material.id"), index=True)
    envmap_id: Mapped[int | None] = mapped_column(fk("envmap.id", "SET NULL"))
    classifier_id: Mapped[int | None] = mapped_column(fk("classifier.id", "SET NULL"))
    split: Mapped[str | None] = mapped_column(sa.String(8))
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)
    blobs: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="pass name -> blob ref")
    saturated_fraction: Mapped[float | None]
    seconds: Mapped[float | None]


class Classifier(TimestampMixin, StatusMixin, ParamsHashMixin, Base):
    """A trained network: the material classifier or the substance segmentation network."""

    __tablename__ = "classifier"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(Str, unique=True)
    kind: Mapped[str] = mapped_column(Short, comment="material | substance")
    architecture: Mapped[str] = mapped_column(sa.String(64))
    config: Mapped[dict[str, Any]] = mapped_column(default=dict)
    material_set_hash: Mapped[str | None] = mapped_column(sa.String(64))
    materials: Mapped[list[Any]] = mapped_column(
        default=list, comment="material ids in output order (index 0 = background)"
    )
    parent_id: Mapped[int | None] = mapped_column(fk("classifier.id", "SET NULL"))
    checkpoint_blob: Mapped[str | None] = mapped_column(sa.String(80))
    epoch: Mapped[int] = mapped_column(default=0)
    metrics: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Assignment(TimestampMixin, ParamsHashMixin, Base):
    """A material chosen for a part of a pair by a method (the classifier or a baseline), ranked."""

    __tablename__ = "assignment"
    __table_args__ = (sa.UniqueConstraint("pair_id", "part_id", "method_key", "rank"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(fk("pair.id"), index=True)
    part_id: Mapped[int] = mapped_column(fk("part.id"), index=True)
    method: Mapped[str] = mapped_column(Short, comment="classifier | builtin | no-classifier | color-match")
    classifier_id: Mapped[int | None] = mapped_column(fk("classifier.id"), index=True)
    method_key: Mapped[str] = mapped_column(
        sa.String(64), comment="method, or classifier:<id>; unique with pair, part and rank"
    )
    rank: Mapped[int] = mapped_column(default=1)
    material_id: Mapped[int | None] = mapped_column(fk("material.id"), index=True)
    score: Mapped[float | None]
    posterior: Mapped[float | None] = mapped_column(
        comment="score normalised over every enabled material of the part (sums to 1); NULL: baselines"
    )
    substance: Mapped[str | None] = mapped_column(Short)
    unobserved: Mapped[bool] = mapped_column(default=False, comment="part not visible: chosen by substance prior")
    params: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="uv scale/rotation/offset used")
    refinement: Mapped[dict[str, Any] | None] = mapped_column(
        comment="fit.refine: tint, roughness_scale, uv_scale, uv_rotation, loss before/after"
    )
