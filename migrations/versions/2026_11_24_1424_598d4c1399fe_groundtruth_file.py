"""groundtruth file registry and evaluation.groundtruth_sha256

Revision ID: 598d4c1399fe
Revises: 5c1a9e7d2b40
Create Date: 2026-11-24 14:24:10.076536

A new table and a nullable column: existing databases gain an empty registry (the next
`photoshape eval --groundtruth FILE` fills it) and their evaluation rows keep a NULL hash. The
downgrade drops both (nothing else refers to them).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '598d4c1399fe'
down_revision: str | None = '5c1a9e7d2b40'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('groundtruth_file',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('path', sa.String(length=1024), nullable=False),
    sa.Column('sha256', sa.String(length=64), nullable=False),
    sa.Column('version', sa.Integer(), nullable=False),
    sa.Column('entries', sa.Integer(), nullable=False, comment='entries matched to ingested exemplars'),
    sa.Column('skipped', sa.Integer(), nullable=False, comment='entries left out (bad or unknown names)'),
    sa.Column('registered_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('used_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_groundtruth_file')),
    sa.UniqueConstraint('path', name=op.f('uq_groundtruth_file__path'))
    )
    with op.batch_alter_table('groundtruth_file', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_groundtruth_file__sha256'), ['sha256'], unique=False)
        batch_op.create_index(batch_op.f('ix_groundtruth_file__used_at'), ['used_at'], unique=False)

    with op.batch_alter_table('evaluation', schema=None) as batch_op:
        batch_op.add_column(sa.Column('groundtruth_sha256', sa.String(length=64), nullable=True, comment='sha256 of the ground-truth file scored against (groundtruth_file)'))
        batch_op.create_index(batch_op.f('ix_evaluation__groundtruth_sha256'), ['groundtruth_sha256'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('evaluation', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_evaluation__groundtruth_sha256'))
        batch_op.drop_column('groundtruth_sha256')

    with op.batch_alter_table('groundtruth_file', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_groundtruth_file__used_at'))
        batch_op.drop_index(batch_op.f('ix_groundtruth_file__sha256'))

    op.drop_table('groundtruth_file')
