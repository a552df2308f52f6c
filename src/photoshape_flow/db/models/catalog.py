"""The collection's inputs (section 3): shapes with their material parts, exemplar photos,
materials and environment maps, each an ingested item with its provenance."""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column, relationship

from photoshape_flow.db.base import (
    Base,
    ExcludeMixin,
    ParamsHashMixin,
    ProvenanceMixin,
    Short,
    SourcedItemMixin,
    StatusMixin,
    Str,
    TimestampMixin,
    fk,
)


class Shape(SourcedItemMixin, TimestampMixin, StatusMixin, ExcludeMixin, ProvenanceMixin, ParamsHashMixin, Base):
    """An imported 3D model, preprocessed into the unit cube with UVs per material part."""

    __tablename__ = "shape"
    __table_args__ = (sa.UniqueConstraint("source", "source_id"),)

    split: Mapped[str] = mapped_column(sa.String(8), default="train", server_default="train")
    mesh_blob: Mapped[str | None] = mapped_column(sa.String(80))
    num_vertices: Mapped[int | None]
    num_faces: Mapped[int | None]
    num_parts: Mapped[int | None]
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)

    parts: Mapped[list[Part]] = relationship(
        back_populates="shape", cascade="all, delete-orphan", order_by="Part.index", passive_deletes=True
    )


class Part(TimestampMixin, Base):
    """A material part of a shape (an OBJ material group): the unit that receives one material."""

    __tablename__ = "part"
    __table_args__ = (sa.UniqueConstraint("shape_id", "index"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    shape_id: Mapped[int] = mapped_column(fk("shape.id"), index=True)
    index: Mapped[int] = mapped_column(comment="1-based; the value of this part in part-ID maps (0 = background)")
    name: Mapped[str] = mapped_column(Str)
    num_faces: Mapped[int] = mapped_column(default=0)
    area_world: Mapped[float] = mapped_column(default=0.0)
    area_uv: Mapped[float] = mapped_column(default=0.0)
    uv_density: Mapped[float] = mapped_column(
        default=1.0, comment="D_i = A_uv / A_world (section 5.1); the renderer scales UVs by 1/sqrt(D_i)"
    )
    builtin_material: Mapped[dict[str, Any]] = mapped_column(default=dict)
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)

    shape: Mapped[Shape] = relationship(back_populates="parts")


class Exemplar(SourcedItemMixin, TimestampMixin, StatusMixin, ExcludeMixin, ProvenanceMixin, ParamsHashMixin, Base):
    """A cleaned product photo: foreground mask, tight square crop."""

    __tablename__ = "exemplar"
    __table_args__ = (sa.UniqueConstraint("source", "source_id"),)

    image_blob: Mapped[str | None] = mapped_column(sa.String(80))
    mask_blob: Mapped[str | None] = mapped_column(sa.String(80))
    native_width: Mapped[int | None]
    native_height: Mapped[int | None]
    size: Mapped[int | None] = mapped_column(comment="side of the square crop as stored")
    foreground_fraction: Mapped[float | None]
    duplicate_of_id: Mapped[int | None] = mapped_column(fk("exemplar.id", "SET NULL"))
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Material(TimestampMixin, StatusMixin, ProvenanceMixin, ParamsHashMixin, Base):
    """An SVBRDF (maps) or analytic material, with its substance and texture scale."""

    __tablename__ = "material"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(Str, unique=True)
    substance: Mapped[str] = mapped_column(Short, index=True)
    kind: Mapped[str] = mapped_column(Short, default="svbrdf", comment="svbrdf | analytic")
    maps: Mapped[dict[str, Any]] = mapped_column(
        default=dict, comment="channel -> blob ref: albedo (sRGB), roughness, metallic, specular, normal (GL), height"
    )
    params: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="analytic constants")
    default_scale: Mapped[float] = mapped_column(
        default=0.25, comment="world size of one texture tile in unit-cube units"
    )
    source: Mapped[str | None] = mapped_column(sa.String(64))
    preview_blob: Mapped[str | None] = mapped_column(sa.String(80))
    enabled: Mapped[bool] = mapped_column(default=True, server_default=sa.true())
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Envmap(TimestampMixin, StatusMixin, ProvenanceMixin, Base):
    """An equirectangular HDR environment map."""

    __tablename__ = "envmap"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(Str, unique=True)
    blob: Mapped[str | None] = mapped_column(sa.String(80))
    width: Mapped[int | None]
    height: Mapped[int | None]
    split: Mapped[str] = mapped_column(sa.String(8), default="train", server_default="train")
    enabled: Mapped[bool] = mapped_column(default=True, server_default=sa.true())
    meta: Mapped[dict[str, Any]] = mapped_column(default=dict)
