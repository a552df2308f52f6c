"""evaluation.ci_low / ci_high: each figure's 95% bootstrap interval over exemplars

Revision ID: 7d3f0e2a9c15
Revises: 7c2d9e4b1f05
Create Date: 2026-11-24 19:00:00

Two nullable columns: rows evaluated before keep NULL (no interval was computed); the next
`photoshape eval` fills them. The downgrade drops them.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '7d3f0e2a9c15'
down_revision: str | None = '7c2d9e4b1f05'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('evaluation', schema=None) as batch_op:
        batch_op.add_column(sa.Column('ci_low', sa.Double(), nullable=True,
                                      comment='lower end of the 95% bootstrap interval over exemplars'))
        batch_op.add_column(sa.Column('ci_high', sa.Double(), nullable=True,
                                      comment='upper end of the 95% bootstrap interval over exemplars'))


def downgrade() -> None:
    with op.batch_alter_table('evaluation', schema=None) as batch_op:
        batch_op.drop_column('ci_high')
        batch_op.drop_column('ci_low')
