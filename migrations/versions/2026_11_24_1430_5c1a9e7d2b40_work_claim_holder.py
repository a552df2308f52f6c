"""work claim holder: host, pid, process start time and worker name of each claim

Revision ID: 5c1a9e7d2b40
Revises: 5c1e7b2d9f40
Create Date: 2026-11-24 14:30:00.000000

Four nullable columns: existing claims keep only their `worker` string (their holder is never
provably dead, so they wait for their lease as before). The downgrade drops the columns.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '5c1a9e7d2b40'
down_revision: str | None = '5c1e7b2d9f40'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

COLUMNS = ('holder_host', 'holder_pid', 'holder_started', 'holder_name')


def upgrade() -> None:
    with op.batch_alter_table('work_claim', schema=None) as batch_op:
        batch_op.add_column(sa.Column('holder_host', sa.String(length=128), nullable=True,
                                      comment='host name of the claiming process'))
        batch_op.add_column(sa.Column('holder_pid', sa.Integer(), nullable=True, comment='its process id'))
        batch_op.add_column(sa.Column('holder_started', sa.String(length=32), nullable=True,
                                      comment='its start time (clock ticks since boot): a reused pid differs'))
        batch_op.add_column(sa.Column('holder_name', sa.String(length=128), nullable=True,
                                      comment='worker name, e.g. photoshape run'))


def downgrade() -> None:
    with op.batch_alter_table('work_claim', schema=None) as batch_op:
        for name in reversed(COLUMNS):
            batch_op.drop_column(name)
