"""pipeline_run.holder_host / holder_pid / holder_started: who runs it, so a dead run is told from a live one

Revision ID: 8a4e1c7f2b36
Revises: 7d3f0e2a9c15
Create Date: 2026-11-27 09:00:00

Three nullable columns, as on work_claim: a run killed before it could record its end stayed
`running` forever; with its process recorded, `db.holder.is_dead` proves it gone and the run is
marked `died`. Runs recorded before keep NULL (nothing provable about them). The downgrade drops them.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '8a4e1c7f2b36'
down_revision: str | None = '7d3f0e2a9c15'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('pipeline_run', schema=None) as batch_op:
        batch_op.add_column(sa.Column('holder_host', sa.String(length=128), nullable=True,
                                      comment='host name of the running process'))
        batch_op.add_column(sa.Column('holder_pid', sa.Integer(), nullable=True, comment='its process id'))
        batch_op.add_column(sa.Column('holder_started', sa.String(length=32), nullable=True,
                                      comment='its start time (clock ticks since boot): a reused pid differs'))


def downgrade() -> None:
    with op.batch_alter_table('pipeline_run', schema=None) as batch_op:
        batch_op.drop_column('holder_started')
        batch_op.drop_column('holder_pid')
        batch_op.drop_column('holder_host')
