"""exemplar match table: the coarse-alignment reverse index as rows

Revision ID: a6ec6d087746
Revises: 80193f30daa2
Create Date: 2026-11-21 22:24:34.673242

Until this revision the reverse index (per exemplar, the top-k (shape, view) matches) was kept as
`exemplar_feature` rows with descriptor ``topk:<descriptor>:<viewpoint set id>[:<category>]`` and a
.npy blob. Those blobs live in the blob store, which a migration cannot rely on reaching, so the
upgrade deletes the rows instead of converting them: the next coarse-alignment run finds no list
for those exemplars and searches them again against every shape, which gives the same lists and
leaves the pairs as they are (the stage is idempotent). The downgrade drops the table; the old code
then re-searches every exemplar the same way.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = 'a6ec6d087746'
down_revision: str | None = '80193f30daa2'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('exemplar_match',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('exemplar_id', sa.Integer(), nullable=False),
    sa.Column('viewpoint_set_id', sa.Integer(), nullable=False),
    sa.Column('descriptor', sa.String(length=64), nullable=False, comment='descriptor name, e.g. hog-insensitive9'),
    sa.Column('scope', sa.String(length=64), server_default='', nullable=False, comment="category the search was restricted to, or ''"),
    sa.Column('rank', sa.Integer(), nullable=False, comment="rank of the shape among the exemplar's matches (1 = best)"),
    sa.Column('shape_id', sa.Integer(), nullable=False),
    sa.Column('view_index', sa.Integer(), nullable=False, comment="index of the shape's best view in the viewpoint set"),
    sa.Column('distance', sa.Double(), nullable=False, comment='squared L2 distance of the descriptors'),
    sa.Column('searched_at', sa.DateTime(timezone=True), nullable=False, comment="when this exemplar's list was last searched"),
    sa.Column('created_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('params_hash', sa.String(length=64), server_default='', nullable=False),
    sa.ForeignKeyConstraint(['exemplar_id'], ['exemplar.id'], name=op.f('fk_exemplar_match__exemplar_id__exemplar'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['shape_id'], ['shape.id'], name=op.f('fk_exemplar_match__shape_id__shape'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['viewpoint_set_id'], ['viewpoint_set.id'], name=op.f('fk_exemplar_match__viewpoint_set_id__viewpoint_set'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_exemplar_match')),
    sa.UniqueConstraint('exemplar_id', 'viewpoint_set_id', 'descriptor', 'scope', 'rank', name=op.f('uq_exemplar_match__exemplar_id_vpset_descriptor_scope_rank'))
    )
    with op.batch_alter_table('exemplar_match', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_exemplar_match__shape_id'), ['shape_id'], unique=False)

    # the old reverse-index rows: re-searched by the next coarse-alignment run (see the docstring)
    exemplar_feature = sa.table('exemplar_feature', sa.column('descriptor', sa.String(64)))
    op.execute(exemplar_feature.delete().where(exemplar_feature.c.descriptor.like('topk:%')))


def downgrade() -> None:
    with op.batch_alter_table('exemplar_match', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_exemplar_match__shape_id'))

    op.drop_table('exemplar_match')
