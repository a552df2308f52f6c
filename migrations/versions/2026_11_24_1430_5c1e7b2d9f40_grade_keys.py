"""grade keys: a grade names the PhotoShape it was given to (method key + assignment-set key)

Revision ID: 5c1e7b2d9f40
Revises: 90238d22ce60
Create Date: 2026-11-24 14:30:00

Grades were keyed by (pair, grader), so a grade given to one classifier's PhotoShape showed on the
next classifier's different PhotoShape of the same pair. The grade now also records the method key
and the key of the rank-1 assignment set it showed (`pipeline.photoshapes.assignment_set_keys`),
unique with pair and grader.

Backfill: each existing grade gets the method of its pair's newest published exemplar-view render
(``rendering`` kind ``photoshape``, status ok) and that method's current assignment-set key; a pair
never published, or whose method has no rank-1 rows any more, keeps NULL keys (a legacy grade:
queryable, shown on no PhotoShape). The key is computed as the application's function computes it, so it
matches what `photoshape grade` and the gallery compute at this revision: the function is
frozen here (`_assignment_set_keys`, raw SQL, no refinement column yet) so that later changes to the
application cannot change what this migration writes; tests/db/test_migrations.py checks it equals
the application's `publish.photoshapes.assignment_set_keys`. Downgrade: drops the columns and keeps
one grade per (pair, grader), the newest (highest id), as the old unique key requires.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from alembic import op

revision: str = '5c1e7b2d9f40'
down_revision: str | None = '90238d22ce60'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _assignment_set_keys(conn: sa.Connection, wanted: set[tuple[int, str]]) -> dict[tuple[int, str], str]:
    """(pair_id, method_key) -> sha256 of the sorted-key JSON of its rank-1 rows, as the application
    computed it at this revision (no refinement column existed)."""
    rows: dict[tuple[int, str], list[list[Any]]] = {}
    if not wanted:
        return {}
    result = conn.execute(sa.text(
        "SELECT pair_id, method_key, part_id, material_id, substance, classifier_id, params FROM assignment "
        "WHERE rank = 1 ORDER BY pair_id, method_key, part_id"))
    for pair_id, method_key, part_id, material_id, substance, classifier_id, params in result:
        if (pair_id, method_key) in wanted:
            params = json.loads(params) if isinstance(params, str) else params
            rows.setdefault((pair_id, method_key), []).append(
                [part_id, material_id, substance, classifier_id, (params or {}).get("uv")])
    return {key: hashlib.sha256(json.dumps({"method_key": key[1], "parts": parts}, sort_keys=True,
                                           default=str).encode()).hexdigest()
            for key, parts in rows.items()}


def _backfill(conn: sa.Connection) -> None:
    grades = conn.execute(sa.text("SELECT id, pair_id FROM grade")).all()
    published: dict[int, str] = {}
    for pair_id in sorted({p for _, p in grades}):
        key = conn.execute(sa.text(
            "SELECT key FROM rendering WHERE kind = 'photoshape' AND status = 'ok' AND pair_id = :p "
            "AND key LIKE '%/exemplar' ORDER BY id DESC LIMIT 1"), {"p": pair_id}).scalar()
        if key and key.count("/") >= 2:
            published[pair_id] = key.split("/", 1)[1].rsplit("/", 1)[0]
    keys = _assignment_set_keys(conn, set(published.items()))
    for grade_id, pair_id in grades:
        method_key = published.get(pair_id)
        set_key = keys.get((pair_id, method_key)) if method_key else None
        if set_key is not None:
            conn.execute(sa.text("UPDATE grade SET method_key = :m, assignment_set = :k WHERE id = :i"),
                         {"m": method_key, "k": set_key, "i": grade_id})


def upgrade() -> None:
    with op.batch_alter_table('grade', schema=None) as batch_op:
        batch_op.add_column(sa.Column('method_key', sa.String(length=64), nullable=True,
                                      comment="the graded PhotoShape's method key"))
        batch_op.add_column(sa.Column('assignment_set', sa.String(length=64), nullable=True,
                                      comment='key of the rank-1 assignment set it showed; NULL: legacy grade'))
        batch_op.drop_constraint('uq_grade__pair_id_grader', type_='unique')
        batch_op.create_unique_constraint(batch_op.f('uq_grade__pair_id_method_key_assignment_set_grader'),
                                          ['pair_id', 'method_key', 'assignment_set', 'grader'])
    _backfill(op.get_bind())


def downgrade() -> None:
    op.execute("DELETE FROM grade WHERE id NOT IN (SELECT MAX(id) FROM grade GROUP BY pair_id, grader)")
    with op.batch_alter_table('grade', schema=None) as batch_op:
        batch_op.drop_constraint('uq_grade__pair_id_method_key_assignment_set_grader', type_='unique')
        batch_op.create_unique_constraint(batch_op.f('uq_grade__pair_id_grader'), ['pair_id', 'grader'])
        batch_op.drop_column('assignment_set')
        batch_op.drop_column('method_key')
