"""assignment refinement: the fit stage's refined parameters on a part's rank-1 `fit` row

Revision ID: 7c2d9e4b1f05
Revises: 3b8e4f1a6c27
Create Date: 2026-11-24 19:00:00

`fit.refine` adjusts the winning material of each refined part (albedo tint, roughness scale, UV
scale and rotation) and measures the image loss before and after; publish renders and exports with
them. NULL on every other row (unrefined pairs, other methods, ranks below 1). The photoshape view
does not show it (it lists materials, not looks), but SQLite's batch mode rebuilds the table, so the
view is dropped and re-created from the previous revision's frozen copy (loaded from its file: one
copy of the SQL). Downgrade drops the column.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from pathlib import Path

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '7c2d9e4b1f05'
down_revision: str | None = '3b8e4f1a6c27'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _view_sql() -> str:
    """The view as revision 3b8e4f1a6c27 froze it (unchanged here)."""
    path = next(Path(__file__).parent.glob("*_3b8e4f1a6c27_*.py"))
    spec = importlib.util.spec_from_file_location("revision_3b8e4f1a6c27", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return str(module.VIEW_WITH_POSTERIOR)


def upgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    with op.batch_alter_table('assignment', schema=None) as batch_op:
        batch_op.add_column(sa.Column(
            'refinement', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'),
            nullable=True, comment='fit.refine: tint, roughness_scale, uv_scale, uv_rotation, loss before/after'))
    op.execute(_view_sql())


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    with op.batch_alter_table('assignment', schema=None) as batch_op:
        batch_op.drop_column('refinement')
    op.execute(_view_sql())
