"""pipeline run: the resolved profile and stage reports of every run

Revision ID: 90238d22ce60
Revises: a6ec6d087746
Create Date: 2026-11-24 11:28:44.757575

A new table only: existing databases gain it empty, and the first run after the upgrade records
its profile. The downgrade drops it (nothing else refers to it).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '90238d22ce60'
down_revision: str | None = 'a6ec6d087746'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('pipeline_run',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('origin', sa.String(length=32), nullable=False, comment='cli | demo | flow'),
    sa.Column('profile_name', sa.String(length=64), nullable=False),
    sa.Column('overrides', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='path -> value as given (--set)'),
    sa.Column('profile', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='every resolved profile value'),
    sa.Column('stages', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='stage names asked for, in order'),
    sa.Column('reports', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False, comment='stage -> StageReport as JSON'),
    sa.Column('status', sa.String(length=32), nullable=False, comment='running | ok | failed'),
    sa.Column('error', sa.Text(), nullable=True),
    sa.Column('started_at', sa.DateTime(timezone=True), server_default=sa.func.now(), nullable=False),
    sa.Column('finished_at', sa.DateTime(timezone=True), nullable=True),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_pipeline_run'))
    )
    with op.batch_alter_table('pipeline_run', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_pipeline_run__profile_name'), ['profile_name'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('pipeline_run', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_pipeline_run__profile_name'))

    op.drop_table('pipeline_run')
