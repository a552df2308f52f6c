"""initial schema: the whole pipeline's tables and the photoshape_candidate view

Revision ID: 80193f30daa2
Revises: (none)
Create Date: 2026-11-21 20:57:22.910258
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '80193f30daa2'
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# Frozen copy of the view as of this revision (later revisions replace it, never edit this one).
CANDIDATE_VIEW_SQL = """CREATE VIEW photoshape_candidate AS
SELECT
    p.id            AS pair_id,
    p.shape_id      AS shape_id,
    p.exemplar_id   AS exemplar_id,
    p.rank          AS pair_rank,
    p.distance      AS hog_distance,
    a.part_id       AS part_id,
    pt."index"      AS part_index,
    pt.name         AS part_name,
    a.method        AS method,
    a.method_key    AS method_key,
    a.classifier_id AS classifier_id,
    a.material_id   AS material_id,
    m.name          AS material_name,
    COALESCE(m.substance, a.substance) AS substance,
    a.score         AS score,
    a.unobserved    AS unobserved,
    al.iou_crf      AS alignment_iou
FROM pair p
JOIN shape s ON s.id = p.shape_id
JOIN exemplar e ON e.id = p.exemplar_id
JOIN assignment a ON a.pair_id = p.id AND a.rank = 1
JOIN part pt ON pt.id = a.part_id
LEFT JOIN material m ON m.id = a.material_id
LEFT JOIN alignment al ON al.pair_id = p.id AND al.method = 'flow-crf'
WHERE NOT p.exclude AND NOT s.exclude AND NOT e.exclude
"""


def upgrade() -> None:
    op.create_table('classifier',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=255), nullable=False),
    sa.Column('kind', sa.String(length=32), nullable=False, comment='material | substance'),
    sa.Column('architecture', sa.String(length=64), nullable=False),
    sa.Column('config', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('material_set_hash', sa.String(length=64), nullable=True),
    sa.Column('materials', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='material ids in output order (index 0 = background)'),
    sa.Column('parent_id', sa.Integer(), nullable=True),
    sa.Column('checkpoint_blob', sa.String(length=80), nullable=True),
    sa.Column('epoch', sa.Integer(), nullable=False),
    sa.Column('metrics', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['parent_id'], ['classifier.id'], name=op.f('fk_classifier__parent_id__classifier'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_classifier')),
    sa.UniqueConstraint('name', name=op.f('uq_classifier__name'))
    )
    with op.batch_alter_table('classifier', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_classifier__status'), ['status'], unique=False)

    op.create_table('envmap',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=255), nullable=False),
    sa.Column('blob', sa.String(length=80), nullable=True),
    sa.Column('width', sa.Integer(), nullable=True),
    sa.Column('height', sa.Integer(), nullable=True),
    sa.Column('split', sa.String(length=8), server_default='train', nullable=False),
    sa.Column('enabled', sa.Boolean(), server_default=sa.true(), nullable=False),
    sa.Column('meta', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('source_path', sa.Text(), nullable=True),
    sa.Column('sha256', sa.String(length=64), nullable=True),
    sa.Column('license', sa.Text(), nullable=True),
    sa.Column('attribution', sa.Text(), nullable=True),
    sa.Column('source_url', sa.Text(), nullable=True),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_envmap')),
    sa.UniqueConstraint('name', name=op.f('uq_envmap__name'))
    )
    with op.batch_alter_table('envmap', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_envmap__sha256'), ['sha256'], unique=False)
        batch_op.create_index(batch_op.f('ix_envmap__status'), ['status'], unique=False)

    op.create_table('evaluation',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('run', sa.String(length=64), nullable=False),
    sa.Column('stage', sa.String(length=32), nullable=False),
    sa.Column('method', sa.String(length=64), server_default='', nullable=False),
    sa.Column('metric', sa.String(length=64), nullable=False),
    sa.Column('value', sa.Double(), nullable=True),
    sa.Column('count', sa.Integer(), nullable=True),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_evaluation')),
    sa.UniqueConstraint('run', 'stage', 'method', 'metric', name=op.f('uq_evaluation__run_stage_method_metric'))
    )
    op.create_table('exemplar',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('source', sa.String(length=64), nullable=False),
    sa.Column('source_id', sa.String(length=255), nullable=False),
    sa.Column('name', sa.String(length=255), nullable=True),
    sa.Column('category', sa.String(length=64), nullable=True),
    sa.Column('image_blob', sa.String(length=80), nullable=True),
    sa.Column('mask_blob', sa.String(length=80), nullable=True),
    sa.Column('native_width', sa.Integer(), nullable=True),
    sa.Column('native_height', sa.Integer(), nullable=True),
    sa.Column('size', sa.Integer(), nullable=True, comment='side of the square crop as stored'),
    sa.Column('foreground_fraction', sa.Double(), nullable=True),
    sa.Column('duplicate_of_id', sa.Integer(), nullable=True),
    sa.Column('meta', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('exclude', sa.Boolean(), server_default=sa.false(), nullable=False),
    sa.Column('exclude_reason', sa.Text(), nullable=True),
    sa.Column('source_path', sa.Text(), nullable=True),
    sa.Column('sha256', sa.String(length=64), nullable=True),
    sa.Column('license', sa.Text(), nullable=True),
    sa.Column('attribution', sa.Text(), nullable=True),
    sa.Column('source_url', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['duplicate_of_id'], ['exemplar.id'], name=op.f('fk_exemplar__duplicate_of_id__exemplar'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_exemplar')),
    sa.UniqueConstraint('source', 'source_id', name=op.f('uq_exemplar__source_source_id'))
    )
    with op.batch_alter_table('exemplar', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_exemplar__category'), ['category'], unique=False)
        batch_op.create_index(batch_op.f('ix_exemplar__sha256'), ['sha256'], unique=False)
        batch_op.create_index(batch_op.f('ix_exemplar__status'), ['status'], unique=False)

    op.create_table('material',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=255), nullable=False),
    sa.Column('substance', sa.String(length=32), nullable=False),
    sa.Column('kind', sa.String(length=32), nullable=False, comment='svbrdf | analytic'),
    sa.Column('maps', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='channel -> blob ref: albedo (sRGB), roughness, metallic, specular, normal (GL), height'),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='analytic constants'),
    sa.Column('default_scale', sa.Double(), nullable=False, comment='world size of one texture tile in unit-cube units'),
    sa.Column('source', sa.String(length=64), nullable=True),
    sa.Column('preview_blob', sa.String(length=80), nullable=True),
    sa.Column('enabled', sa.Boolean(), server_default=sa.true(), nullable=False),
    sa.Column('meta', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('source_path', sa.Text(), nullable=True),
    sa.Column('sha256', sa.String(length=64), nullable=True),
    sa.Column('license', sa.Text(), nullable=True),
    sa.Column('attribution', sa.Text(), nullable=True),
    sa.Column('source_url', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_material')),
    sa.UniqueConstraint('name', name=op.f('uq_material__name'))
    )
    with op.batch_alter_table('material', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_material__sha256'), ['sha256'], unique=False)
        batch_op.create_index(batch_op.f('ix_material__status'), ['status'], unique=False)
        batch_op.create_index(batch_op.f('ix_material__substance'), ['substance'], unique=False)

    op.create_table('shape',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('source', sa.String(length=64), nullable=False),
    sa.Column('source_id', sa.String(length=255), nullable=False),
    sa.Column('name', sa.String(length=255), nullable=True),
    sa.Column('category', sa.String(length=64), nullable=True),
    sa.Column('split', sa.String(length=8), server_default='train', nullable=False),
    sa.Column('mesh_blob', sa.String(length=80), nullable=True),
    sa.Column('num_vertices', sa.Integer(), nullable=True),
    sa.Column('num_faces', sa.Integer(), nullable=True),
    sa.Column('num_parts', sa.Integer(), nullable=True),
    sa.Column('meta', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('exclude', sa.Boolean(), server_default=sa.false(), nullable=False),
    sa.Column('exclude_reason', sa.Text(), nullable=True),
    sa.Column('source_path', sa.Text(), nullable=True),
    sa.Column('sha256', sa.String(length=64), nullable=True),
    sa.Column('license', sa.Text(), nullable=True),
    sa.Column('attribution', sa.Text(), nullable=True),
    sa.Column('source_url', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_shape')),
    sa.UniqueConstraint('source', 'source_id', name=op.f('uq_shape__source_source_id'))
    )
    with op.batch_alter_table('shape', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_shape__category'), ['category'], unique=False)
        batch_op.create_index(batch_op.f('ix_shape__sha256'), ['sha256'], unique=False)
        batch_op.create_index(batch_op.f('ix_shape__status'), ['status'], unique=False)

    op.create_table('viewpoint_set',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=64), nullable=False),
    sa.Column('version', sa.Integer(), nullable=False),
    sa.Column('num_views', sa.Integer(), nullable=False),
    sa.Column('cameras', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='[[azimuth, elevation, distance, fov_deg], ...] in radians except fov'),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_viewpoint_set')),
    sa.UniqueConstraint('name', 'version', name=op.f('uq_viewpoint_set__name_version'))
    )
    op.create_table('work_claim',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('stage', sa.String(length=32), nullable=False),
    sa.Column('item_key', sa.String(length=255), nullable=False),
    sa.Column('state', sa.String(length=32), nullable=False, comment='claimed | done | failed'),
    sa.Column('worker', sa.String(length=128), nullable=True),
    sa.Column('lease_expires_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('attempts', sa.Integer(), nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_work_claim')),
    sa.UniqueConstraint('stage', 'item_key', name=op.f('uq_work_claim__stage_item_key'))
    )
    op.create_table('exemplar_feature',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('exemplar_id', sa.Integer(), nullable=False),
    sa.Column('descriptor', sa.String(length=64), nullable=False),
    sa.Column('feature_blob', sa.String(length=80), nullable=True),
    sa.Column('dims', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['exemplar_id'], ['exemplar.id'], name=op.f('fk_exemplar_feature__exemplar_id__exemplar'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_exemplar_feature')),
    sa.UniqueConstraint('exemplar_id', 'descriptor', name=op.f('uq_exemplar_feature__exemplar_id_descriptor'))
    )
    with op.batch_alter_table('exemplar_feature', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_exemplar_feature__exemplar_id'), ['exemplar_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_exemplar_feature__status'), ['status'], unique=False)

    op.create_table('pair',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('shape_id', sa.Integer(), nullable=False),
    sa.Column('exemplar_id', sa.Integer(), nullable=False),
    sa.Column('viewpoint_set_id', sa.Integer(), nullable=True),
    sa.Column('descriptor', sa.String(length=64), nullable=True),
    sa.Column('view_index', sa.Integer(), nullable=True),
    sa.Column('rank', sa.Integer(), nullable=False, comment="rank of the exemplar among this shape's exemplars (1 = best)"),
    sa.Column('exemplar_rank', sa.Integer(), nullable=True, comment="rank of the shape among the exemplar's matches"),
    sa.Column('distance', sa.Double(), nullable=False),
    sa.Column('azimuth', sa.Double(), nullable=False),
    sa.Column('elevation', sa.Double(), nullable=False),
    sa.Column('fov', sa.Double(), nullable=False, comment='horizontal field of view, degrees'),
    sa.Column('camera_distance', sa.Double(), nullable=False),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('exclude', sa.Boolean(), server_default=sa.false(), nullable=False),
    sa.Column('exclude_reason', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['exemplar_id'], ['exemplar.id'], name=op.f('fk_pair__exemplar_id__exemplar'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['shape_id'], ['shape.id'], name=op.f('fk_pair__shape_id__shape'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['viewpoint_set_id'], ['viewpoint_set.id'], name=op.f('fk_pair__viewpoint_set_id__viewpoint_set'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_pair')),
    sa.UniqueConstraint('shape_id', 'exemplar_id', name=op.f('uq_pair__shape_id_exemplar_id'))
    )
    with op.batch_alter_table('pair', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_pair__exemplar_id'), ['exemplar_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_pair__shape_id'), ['shape_id'], unique=False)

    op.create_table('part',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('shape_id', sa.Integer(), nullable=False),
    sa.Column('index', sa.Integer(), nullable=False, comment='1-based; the value of this part in part-ID maps (0 = background)'),
    sa.Column('name', sa.String(length=255), nullable=False),
    sa.Column('num_faces', sa.Integer(), nullable=False),
    sa.Column('area_world', sa.Double(), nullable=False),
    sa.Column('area_uv', sa.Double(), nullable=False),
    sa.Column('uv_density', sa.Double(), nullable=False, comment='D_i = A_uv / A_world (section 5.1); the renderer scales UVs by 1/sqrt(D_i)'),
    sa.Column('builtin_material', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('meta', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.ForeignKeyConstraint(['shape_id'], ['shape.id'], name=op.f('fk_part__shape_id__shape'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_part')),
    sa.UniqueConstraint('shape_id', 'index', name=op.f('uq_part__shape_id_index'))
    )
    with op.batch_alter_table('part', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_part__shape_id'), ['shape_id'], unique=False)

    op.create_table('view_feature',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('shape_id', sa.Integer(), nullable=False),
    sa.Column('viewpoint_set_id', sa.Integer(), nullable=False),
    sa.Column('descriptor', sa.String(length=64), nullable=False),
    sa.Column('feature_blob', sa.String(length=80), nullable=True),
    sa.Column('dims', sa.Integer(), nullable=True),
    sa.Column('num_views', sa.Integer(), nullable=True),
    sa.Column('meta', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['shape_id'], ['shape.id'], name=op.f('fk_view_feature__shape_id__shape'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['viewpoint_set_id'], ['viewpoint_set.id'], name=op.f('fk_view_feature__viewpoint_set_id__viewpoint_set'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_view_feature')),
    sa.UniqueConstraint('shape_id', 'viewpoint_set_id', 'descriptor', name=op.f('uq_view_feature__shape_id_viewpoint_set_id_descriptor'))
    )
    with op.batch_alter_table('view_feature', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_view_feature__shape_id'), ['shape_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_view_feature__status'), ['status'], unique=False)
        batch_op.create_index(batch_op.f('ix_view_feature__viewpoint_set_id'), ['viewpoint_set_id'], unique=False)

    op.create_table('alignment',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('pair_id', sa.Integer(), nullable=False),
    sa.Column('method', sa.String(length=64), nullable=False),
    sa.Column('coarse_blob', sa.String(length=80), nullable=True),
    sa.Column('flow_blob', sa.String(length=80), nullable=True),
    sa.Column('crf_blob', sa.String(length=80), nullable=True),
    sa.Column('iou_coarse', sa.Double(), nullable=True),
    sa.Column('iou_flow', sa.Double(), nullable=True),
    sa.Column('iou_crf', sa.Double(), nullable=True),
    sa.Column('accuracy_coarse', sa.Double(), nullable=True, comment='part-label pixel accuracy vs demo ground truth'),
    sa.Column('accuracy_flow', sa.Double(), nullable=True),
    sa.Column('accuracy_crf', sa.Double(), nullable=True),
    sa.Column('seconds', sa.Double(), nullable=True),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['pair_id'], ['pair.id'], name=op.f('fk_alignment__pair_id__pair'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_alignment')),
    sa.UniqueConstraint('pair_id', 'method', name=op.f('uq_alignment__pair_id_method'))
    )
    with op.batch_alter_table('alignment', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_alignment__pair_id'), ['pair_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_alignment__status'), ['status'], unique=False)

    op.create_table('assignment',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('pair_id', sa.Integer(), nullable=False),
    sa.Column('part_id', sa.Integer(), nullable=False),
    sa.Column('method', sa.String(length=32), nullable=False, comment='classifier | builtin | no-classifier | color-match'),
    sa.Column('classifier_id', sa.Integer(), nullable=True),
    sa.Column('method_key', sa.String(length=64), nullable=False, comment='method, or classifier:<id>; unique with pair, part and rank'),
    sa.Column('rank', sa.Integer(), nullable=False),
    sa.Column('material_id', sa.Integer(), nullable=True),
    sa.Column('score', sa.Double(), nullable=True),
    sa.Column('substance', sa.String(length=32), nullable=True),
    sa.Column('unobserved', sa.Boolean(), nullable=False, comment='part not visible: chosen by substance prior'),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='uv scale/rotation/offset used'),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['classifier_id'], ['classifier.id'], name=op.f('fk_assignment__classifier_id__classifier'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['material_id'], ['material.id'], name=op.f('fk_assignment__material_id__material'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['pair_id'], ['pair.id'], name=op.f('fk_assignment__pair_id__pair'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['part_id'], ['part.id'], name=op.f('fk_assignment__part_id__part'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_assignment')),
    sa.UniqueConstraint('pair_id', 'part_id', 'method_key', 'rank', name=op.f('uq_assignment__pair_id_part_id_method_key_rank'))
    )
    with op.batch_alter_table('assignment', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_assignment__classifier_id'), ['classifier_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_assignment__material_id'), ['material_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_assignment__pair_id'), ['pair_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_assignment__part_id'), ['part_id'], unique=False)

    op.create_table('grade',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('pair_id', sa.Integer(), nullable=False),
    sa.Column('label', sa.String(length=32), nullable=False),
    sa.Column('note', sa.Text(), nullable=True),
    sa.Column('grader', sa.String(length=64), server_default='user', nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.ForeignKeyConstraint(['pair_id'], ['pair.id'], name=op.f('fk_grade__pair_id__pair'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_grade')),
    sa.UniqueConstraint('pair_id', 'grader', name=op.f('uq_grade__pair_id_grader'))
    )
    with op.batch_alter_table('grade', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_grade__pair_id'), ['pair_id'], unique=False)

    op.create_table('part_substance',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('pair_id', sa.Integer(), nullable=False),
    sa.Column('part_id', sa.Integer(), nullable=False),
    sa.Column('classifier_id', sa.Integer(), nullable=True),
    sa.Column('observed', sa.Boolean(), nullable=False, comment='false: the part has no pixels in the exemplar'),
    sa.Column('substance', sa.String(length=32), nullable=True),
    sa.Column('confidence', sa.Double(), nullable=True),
    sa.Column('pixel_count', sa.Integer(), nullable=False),
    sa.Column('probs', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['classifier_id'], ['classifier.id'], name=op.f('fk_part_substance__classifier_id__classifier'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['pair_id'], ['pair.id'], name=op.f('fk_part_substance__pair_id__pair'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['part_id'], ['part.id'], name=op.f('fk_part_substance__part_id__part'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_part_substance')),
    sa.UniqueConstraint('pair_id', 'part_id', name=op.f('uq_part_substance__pair_id_part_id'))
    )
    with op.batch_alter_table('part_substance', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_part_substance__pair_id'), ['pair_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_part_substance__part_id'), ['part_id'], unique=False)

    op.create_table('rendering',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=32), nullable=False),
    sa.Column('key', sa.String(length=255), nullable=False, comment='natural key within the kind (also the seed source)'),
    sa.Column('shape_id', sa.Integer(), nullable=True),
    sa.Column('pair_id', sa.Integer(), nullable=True),
    sa.Column('material_id', sa.Integer(), nullable=True),
    sa.Column('envmap_id', sa.Integer(), nullable=True),
    sa.Column('classifier_id', sa.Integer(), nullable=True),
    sa.Column('split', sa.String(length=8), nullable=True),
    sa.Column('params', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('blobs', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='pass name -> blob ref'),
    sa.Column('saturated_fraction', sa.Double(), nullable=True),
    sa.Column('seconds', sa.Double(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('status', sa.String(length=16), server_default='ok', nullable=False),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('exclude', sa.Boolean(), server_default=sa.false(), nullable=False),
    sa.Column('exclude_reason', sa.Text(), nullable=True),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['classifier_id'], ['classifier.id'], name=op.f('fk_rendering__classifier_id__classifier'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['envmap_id'], ['envmap.id'], name=op.f('fk_rendering__envmap_id__envmap'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['material_id'], ['material.id'], name=op.f('fk_rendering__material_id__material'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['pair_id'], ['pair.id'], name=op.f('fk_rendering__pair_id__pair'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['shape_id'], ['shape.id'], name=op.f('fk_rendering__shape_id__shape'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_rendering')),
    sa.UniqueConstraint('kind', 'key', name=op.f('uq_rendering__kind_key'))
    )
    with op.batch_alter_table('rendering', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_rendering__kind'), ['kind'], unique=False)
        batch_op.create_index(batch_op.f('ix_rendering__material_id'), ['material_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_rendering__pair_id'), ['pair_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_rendering__shape_id'), ['shape_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_rendering__status'), ['status'], unique=False)


    op.execute(CANDIDATE_VIEW_SQL)

def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    with op.batch_alter_table('rendering', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_rendering__status'))
        batch_op.drop_index(batch_op.f('ix_rendering__shape_id'))
        batch_op.drop_index(batch_op.f('ix_rendering__pair_id'))
        batch_op.drop_index(batch_op.f('ix_rendering__material_id'))
        batch_op.drop_index(batch_op.f('ix_rendering__kind'))

    op.drop_table('rendering')
    with op.batch_alter_table('part_substance', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_part_substance__part_id'))
        batch_op.drop_index(batch_op.f('ix_part_substance__pair_id'))

    op.drop_table('part_substance')
    with op.batch_alter_table('grade', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_grade__pair_id'))

    op.drop_table('grade')
    with op.batch_alter_table('assignment', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_assignment__part_id'))
        batch_op.drop_index(batch_op.f('ix_assignment__pair_id'))
        batch_op.drop_index(batch_op.f('ix_assignment__material_id'))
        batch_op.drop_index(batch_op.f('ix_assignment__classifier_id'))

    op.drop_table('assignment')
    with op.batch_alter_table('alignment', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_alignment__status'))
        batch_op.drop_index(batch_op.f('ix_alignment__pair_id'))

    op.drop_table('alignment')
    with op.batch_alter_table('view_feature', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_view_feature__viewpoint_set_id'))
        batch_op.drop_index(batch_op.f('ix_view_feature__status'))
        batch_op.drop_index(batch_op.f('ix_view_feature__shape_id'))

    op.drop_table('view_feature')
    with op.batch_alter_table('part', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_part__shape_id'))

    op.drop_table('part')
    with op.batch_alter_table('pair', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_pair__shape_id'))
        batch_op.drop_index(batch_op.f('ix_pair__exemplar_id'))

    op.drop_table('pair')
    with op.batch_alter_table('exemplar_feature', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_exemplar_feature__status'))
        batch_op.drop_index(batch_op.f('ix_exemplar_feature__exemplar_id'))

    op.drop_table('exemplar_feature')
    op.drop_table('work_claim')
    op.drop_table('viewpoint_set')
    with op.batch_alter_table('shape', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_shape__status'))
        batch_op.drop_index(batch_op.f('ix_shape__sha256'))
        batch_op.drop_index(batch_op.f('ix_shape__category'))

    op.drop_table('shape')
    with op.batch_alter_table('material', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_material__substance'))
        batch_op.drop_index(batch_op.f('ix_material__status'))
        batch_op.drop_index(batch_op.f('ix_material__sha256'))

    op.drop_table('material')
    with op.batch_alter_table('exemplar', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_exemplar__status'))
        batch_op.drop_index(batch_op.f('ix_exemplar__sha256'))
        batch_op.drop_index(batch_op.f('ix_exemplar__category'))

    op.drop_table('exemplar')
    op.drop_table('evaluation')
    with op.batch_alter_table('envmap', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_envmap__status'))
        batch_op.drop_index(batch_op.f('ix_envmap__sha256'))

    op.drop_table('envmap')
    with op.batch_alter_table('classifier', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_classifier__status'))

    op.drop_table('classifier')
