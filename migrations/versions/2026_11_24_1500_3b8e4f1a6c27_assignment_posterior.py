"""assignment posterior: each ranked material's score normalised over the part's enabled materials

Revision ID: 3b8e4f1a6c27
Revises: 598d4c1399fe
Create Date: 2026-11-24 15:00:00

Scores are products of three experts and top out near 0.3, so "every part at least 0.5" found
nothing. `assignment.posterior` holds the ranking's score divided by its sum over every enabled
material of the part (`classify.ranking.posterior`), and `photoshape_candidate` exposes it.
Existing rows keep NULL: only the ranking sees every material's score, so the posterior cannot be
rebuilt from the stored top k; the ranking's code version changed with it (inference-9), so the
next inference run re-ranks every pair and fills it. Downgrade drops the column and restores the
view without it.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '3b8e4f1a6c27'
down_revision: str | None = '598d4c1399fe'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# Frozen copies of the view before and after this revision (later revisions replace it, never edit these).
VIEW_WITHOUT_POSTERIOR = """CREATE VIEW photoshape_candidate AS
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

# the same view with one more column, after the score
VIEW_WITH_POSTERIOR = VIEW_WITHOUT_POSTERIOR.replace(
    "    a.score         AS score,\n", "    a.score         AS score,\n    a.posterior     AS posterior,\n")
assert VIEW_WITH_POSTERIOR != VIEW_WITHOUT_POSTERIOR


def upgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    with op.batch_alter_table('assignment', schema=None) as batch_op:
        batch_op.add_column(sa.Column('posterior', sa.Double(), nullable=True, comment=(
            'score normalised over every enabled material of the part (sums to 1); NULL: baselines')))
    op.execute(VIEW_WITH_POSTERIOR)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    with op.batch_alter_table('assignment', schema=None) as batch_op:
        batch_op.drop_column('posterior')
    op.execute(VIEW_WITHOUT_POSTERIOR)
