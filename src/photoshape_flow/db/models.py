"""The metadata schema of the whole pipeline, in the paper's vocabulary.

Every table has a natural unique key so that each write is an idempotent upsert; rows produced by
a step that can fail on one item carry `status` + `error`; result rows carry `params_hash`.
Files (meshes, images, maps, features, checkpoints) live in the blob store and rows hold their refs.
Change the schema only through a new Alembic migration (``migrations/versions``).
"""

from __future__ import annotations

import datetime as dt
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, mapped_column, relationship

from photoshape_flow.db.base import (
    Base,
    ExcludeMixin,
    ParamsHashMixin,
    ProvenanceMixin,
    StatusMixin,
    TimestampMixin,
    utcnow,
)

Str = sa.String(255)
Short = sa.String(32)


def _fk(target: str, ondelete: str = "CASCADE") -> sa.ForeignKey:
    return sa.ForeignKey(target, ondelete=ondelete)


class Shape(TimestampMixin, StatusMixin, ExcludeMixin, ProvenanceMixin, ParamsHashMixin, Base):
    """An imported 3D model, preprocessed into the unit cube with UVs per material part."""

    __tablename__ = "shape"
    __table_args__ = (sa.UniqueConstraint("source", "source_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    source: Mapped[str] = mapped_column(sa.String(64))
    source_id: Mapped[str] = mapped_column(Str)
    name: Mapped[str | None] = mapped_column(Str)
    category: Mapped[str | None] = mapped_column(sa.String(64), index=True)
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
    shape_id: Mapped[int] = mapped_column(_fk("shape.id"), index=True)
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


class Exemplar(TimestampMixin, StatusMixin, ExcludeMixin, ProvenanceMixin, ParamsHashMixin, Base):
    """A cleaned product photo: foreground mask, tight square crop."""

    __tablename__ = "exemplar"
    __table_args__ = (sa.UniqueConstraint("source", "source_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    source: Mapped[str] = mapped_column(sa.String(64))
    source_id: Mapped[str] = mapped_column(Str)
    name: Mapped[str | None] = mapped_column(Str)
    category: Mapped[str | None] = mapped_column(sa.String(64), index=True)
    image_blob: Mapped[str | None] = mapped_column(sa.String(80))
    mask_blob: Mapped[str | None] = mapped_column(sa.String(80))
    native_width: Mapped[int | None]
    native_height: Mapped[int | None]
    size: Mapped[int | None] = mapped_column(comment="side of the square crop as stored")
    foreground_fraction: Mapped[float | None]
    duplicate_of_id: Mapped[int | None] = mapped_column(_fk("exemplar.id", "SET NULL"))
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
    shape_id: Mapped[int] = mapped_column(_fk("shape.id"), index=True)
    viewpoint_set_id: Mapped[int] = mapped_column(_fk("viewpoint_set.id"), index=True)
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
    exemplar_id: Mapped[int] = mapped_column(_fk("exemplar.id"), index=True)
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
    exemplar_id: Mapped[int] = mapped_column(_fk("exemplar.id"))
    viewpoint_set_id: Mapped[int] = mapped_column(_fk("viewpoint_set.id"))
    descriptor: Mapped[str] = mapped_column(sa.String(64), comment="descriptor name, e.g. hog-insensitive9")
    scope: Mapped[str] = mapped_column(
        sa.String(64), default="", server_default="", comment="category the search was restricted to, or ''"
    )
    rank: Mapped[int] = mapped_column(comment="rank of the shape among the exemplar's matches (1 = best)")
    shape_id: Mapped[int] = mapped_column(_fk("shape.id"), index=True)
    view_index: Mapped[int] = mapped_column(comment="index of the shape's best view in the viewpoint set")
    distance: Mapped[float] = mapped_column(comment="squared L2 distance of the descriptors")
    searched_at: Mapped[dt.datetime] = mapped_column(comment="when this exemplar's list was last searched")


class Pair(TimestampMixin, ExcludeMixin, ParamsHashMixin, Base):
    """A shape-exemplar candidate from coarse alignment, with the retrieved camera."""

    __tablename__ = "pair"
    __table_args__ = (sa.UniqueConstraint("shape_id", "exemplar_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    shape_id: Mapped[int] = mapped_column(_fk("shape.id"), index=True)
    exemplar_id: Mapped[int] = mapped_column(_fk("exemplar.id"), index=True)
    viewpoint_set_id: Mapped[int | None] = mapped_column(_fk("viewpoint_set.id", "SET NULL"))
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
    pair_id: Mapped[int] = mapped_column(_fk("pair.id"), index=True)
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


class PartSubstance(TimestampMixin, ParamsHashMixin, Base):
    """The substance of a part as seen in one pair's exemplar (majority overlap, with confidence)."""

    __tablename__ = "part_substance"
    __table_args__ = (sa.UniqueConstraint("pair_id", "part_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(_fk("pair.id"), index=True)
    part_id: Mapped[int] = mapped_column(_fk("part.id"), index=True)
    classifier_id: Mapped[int | None] = mapped_column(_fk("classifier.id", "SET NULL"))
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
    shape_id: Mapped[int | None] = mapped_column(_fk("shape.id"), index=True)
    pair_id: Mapped[int | None] = mapped_column(_fk("pair.id"), index=True)
    material_id: Mapped[int | None] = mapped_column(_fk("material.id"), index=True)
    envmap_id: Mapped[int | None] = mapped_column(_fk("envmap.id", "SET NULL"))
    classifier_id: Mapped[int | None] = mapped_column(_fk("classifier.id", "SET NULL"))
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
    parent_id: Mapped[int | None] = mapped_column(_fk("classifier.id", "SET NULL"))
    checkpoint_blob: Mapped[str | None] = mapped_column(sa.String(80))
    epoch: Mapped[int] = mapped_column(default=0)
    metrics: Mapped[dict[str, Any]] = mapped_column(default=dict)


class Assignment(TimestampMixin, ParamsHashMixin, Base):
    """A material chosen for a part of a pair by a method (the classifier or a baseline), ranked."""

    __tablename__ = "assignment"
    __table_args__ = (sa.UniqueConstraint("pair_id", "part_id", "method_key", "rank"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(_fk("pair.id"), index=True)
    part_id: Mapped[int] = mapped_column(_fk("part.id"), index=True)
    method: Mapped[str] = mapped_column(Short, comment="classifier | builtin | no-classifier | color-match")
    classifier_id: Mapped[int | None] = mapped_column(_fk("classifier.id"), index=True)
    method_key: Mapped[str] = mapped_column(
        sa.String(64), comment="method, or classifier:<id>; unique with pair, part and rank"
    )
    rank: Mapped[int] = mapped_column(default=1)
    material_id: Mapped[int | None] = mapped_column(_fk("material.id"), index=True)
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


class Evaluation(Base):
    """One metric of one run against ground truth, comparable across runs in SQL."""

    __tablename__ = "evaluation"
    __table_args__ = (sa.UniqueConstraint("run", "stage", "method", "metric"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    run: Mapped[str] = mapped_column(sa.String(64))
    stage: Mapped[str] = mapped_column(sa.String(32))
    method: Mapped[str] = mapped_column(sa.String(64), default="", server_default="")
    metric: Mapped[str] = mapped_column(sa.String(64))
    value: Mapped[float | None]
    count: Mapped[int | None]
    ci_low: Mapped[float | None] = mapped_column(comment="lower end of the 95% bootstrap interval over exemplars")
    ci_high: Mapped[float | None] = mapped_column(comment="upper end of the 95% bootstrap interval over exemplars")
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)
    groundtruth_sha256: Mapped[str | None] = mapped_column(
        sa.String(64), index=True, comment="sha256 of the ground-truth file scored against (groundtruth_file)")
    created_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())


class GroundTruthFileRow(Base):
    """A ground-truth file `photoshape eval` scored against; the newest used is the default next time.

    Keyed by the file's absolute path: an edited file keeps its row and gets its new sha256, while
    the evaluation rows keep the hash they were computed with.
    """

    __tablename__ = "groundtruth_file"

    id: Mapped[int] = mapped_column(primary_key=True)
    path: Mapped[str] = mapped_column(sa.String(1024), unique=True)
    sha256: Mapped[str] = mapped_column(sa.String(64), index=True)
    version: Mapped[int]
    entries: Mapped[int] = mapped_column(default=0, comment="entries matched to ingested exemplars")
    skipped: Mapped[int] = mapped_column(default=0, comment="entries left out (bad or unknown names)")
    registered_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())
    used_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now(), index=True)


class Grade(TimestampMixin, Base):
    """A person's verdict on a PhotoShape, from the original code's result taxonomy.

    Keyed by what was graded, not by the pair alone: the method key and the assignment-set key
    (`publish.photoshapes.assignment_set_keys`) of the rank-1 materials the PhotoShape showed, so
    a new classifier's (or a re-ranked) PhotoShape of the same pair starts ungraded while the old
    grade stays. NULL keys: a grade from before they were recorded whose PhotoShape is unknown.
    """

    __tablename__ = "grade"
    __table_args__ = (sa.UniqueConstraint("pair_id", "method_key", "assignment_set", "grader"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    pair_id: Mapped[int] = mapped_column(_fk("pair.id"), index=True)
    method_key: Mapped[str | None] = mapped_column(sa.String(64), comment="the graded PhotoShape's method key")
    assignment_set: Mapped[str | None] = mapped_column(
        sa.String(64), comment="key of the rank-1 assignment set it showed; NULL: legacy grade")
    label: Mapped[str] = mapped_column(Short)
    note: Mapped[str | None] = mapped_column(sa.Text)
    grader: Mapped[str] = mapped_column(sa.String(64), default="user", server_default="user")


class WorkClaim(TimestampMixin, ParamsHashMixin, Base):
    """Ledger of per-item stage work shared by several workers: claimed (with a lease), done or failed.

    A claim whose lease has expired, or whose holder is provably dead (same host, process gone or
    its pid reused: `db.holder`), may be taken by another worker, so a killed worker's items are
    picked up again; `done` rows make re-runs skip finished items. Live holders renew their lease.
    """

    __tablename__ = "work_claim"
    __table_args__ = (sa.UniqueConstraint("stage", "item_key"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    stage: Mapped[str] = mapped_column(sa.String(32))
    item_key: Mapped[str] = mapped_column(Str)
    state: Mapped[str] = mapped_column(Short, default="claimed", comment="claimed | done | failed")
    worker: Mapped[str | None] = mapped_column(sa.String(128))
    lease_expires_at: Mapped[dt.datetime | None]
    attempts: Mapped[int] = mapped_column(default=0)
    error: Mapped[str | None] = mapped_column(sa.Text)
    holder_host: Mapped[str | None] = mapped_column(sa.String(128), comment="host name of the claiming process")
    holder_pid: Mapped[int | None] = mapped_column(comment="its process id")
    holder_started: Mapped[str | None] = mapped_column(
        sa.String(32), comment="its start time (clock ticks since boot): a reused pid differs")
    holder_name: Mapped[str | None] = mapped_column(sa.String(128), comment="worker name, e.g. photoshape run")


class PipelineRun(Base):
    """One `photoshape run` / `demo` / flow run: the resolved profile it used and what each stage did.

    The newest row tells later runs (the material-added re-run, deployments) which profile the
    collection was built with; `profile` holds every resolved value, `overrides` what was asked for.
    """

    __tablename__ = "pipeline_run"

    id: Mapped[int] = mapped_column(primary_key=True)
    origin: Mapped[str] = mapped_column(sa.String(32), comment="cli | demo | flow")
    profile_name: Mapped[str] = mapped_column(sa.String(64), index=True)
    overrides: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="path -> value as given (--set)")
    profile: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="every resolved profile value")
    stages: Mapped[list[Any]] = mapped_column(default=list, comment="stage names asked for, in order")
    reports: Mapped[dict[str, Any]] = mapped_column(default=dict, comment="stage -> StageReport as JSON")
    status: Mapped[str] = mapped_column(Short, default="running", comment="running | ok | failed")
    error: Mapped[str | None] = mapped_column(sa.Text)
    started_at: Mapped[dt.datetime] = mapped_column(default=utcnow, server_default=sa.func.now())
    finished_at: Mapped[dt.datetime | None]
    holder_host: Mapped[str | None] = mapped_column(sa.String(128), comment="host name of the running process")
    holder_pid: Mapped[int | None] = mapped_column(comment="its process id")
    holder_started: Mapped[str | None] = mapped_column(
        sa.String(32), comment="its start time (clock ticks since boot): a reused pid differs")


ALL_TABLES: tuple[type[Base], ...] = (
    Shape, Part, Exemplar, Material, Envmap, ViewpointSet, ViewFeature, ExemplarFeature, ExemplarMatch,
    Pair, Alignment, PartSubstance, Rendering, Classifier, Assignment, Evaluation, GroundTruthFileRow, Grade,
    WorkClaim, PipelineRun,
)
