"""photoshape_candidate: shape and exemplar names, `published`, the latest `grade`, the gallery's `score`

Revision ID: c4d1a9e05b73
Revises: 8a4e1c7f2b36
Create Date: 2026-11-27 10:00:00

The view had ids only, no published flag and a `score` that was the raw product of experts while
the gallery's "Score" is the mean part confidence. It now carries `shape_name` and `exemplar_name`
(the names the gallery shows), `published` (publish rendered the PhotoShape: its exemplar-view
render of that pair and method key is recorded ok, whatever the method), `grade` (the newest grade
given to that pair's PhotoShape of that method key, any grader), `confidence` (per part: the
posterior, else the method's own score, as the gallery shows it) and `score`, the gallery's: the
mean confidence over the parts seen in the exemplar (all parts when none was). The former raw
product is `ranking_score`. The view now reads `rendering` and `grade` too: a later revision that
rebuilds either table (batch mode on SQLite) drops the view first, as those on `assignment` do.
Downgrade restores the view of revision 3b8e4f1a6c27 (posterior, raw score).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from pathlib import Path

from alembic import op

revision: str = 'c4d1a9e05b73'
down_revision: str | None = '8a4e1c7f2b36'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# Frozen copy of the view this revision creates (later revisions replace it, never edit this).
VIEW_PUBLISHED_GRADE = """CREATE VIEW photoshape_candidate AS
SELECT
    p.id            AS pair_id,
    p.shape_id      AS shape_id,
    COALESCE(NULLIF(s.name, ''), s.source_id) AS shape_name,
    p.exemplar_id   AS exemplar_id,
    COALESCE(NULLIF(e.name, ''), e.source_id) AS exemplar_name,
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
    COALESCE(a.posterior, a.score) AS confidence,
    COALESCE(
        AVG(CASE WHEN NOT COALESCE(a.unobserved, FALSE) THEN COALESCE(a.posterior, a.score) END)
            OVER (PARTITION BY a.pair_id, a.method_key),
        AVG(COALESCE(a.posterior, a.score)) OVER (PARTITION BY a.pair_id, a.method_key)
    )               AS score,
    a.score         AS ranking_score,
    a.posterior     AS posterior,
    a.unobserved    AS unobserved,
    al.iou_crf      AS alignment_iou,
    EXISTS (
        SELECT 1 FROM rendering r
        WHERE r.kind = 'photoshape' AND r.status = 'ok'
          AND r.key = CAST(p.id AS VARCHAR(20)) || '/' || a.method_key || '/exemplar'
    )               AS published,
    (
        SELECT g.label FROM grade g
        WHERE g.pair_id = p.id AND g.method_key = a.method_key
        ORDER BY g.updated_at DESC, g.id DESC
        LIMIT 1
    )               AS grade
FROM pair p
JOIN shape s ON s.id = p.shape_id
JOIN exemplar e ON e.id = p.exemplar_id
JOIN assignment a ON a.pair_id = p.id AND a.rank = 1
JOIN part pt ON pt.id = a.part_id
LEFT JOIN material m ON m.id = a.material_id
LEFT JOIN alignment al ON al.pair_id = p.id AND al.method = 'flow-crf'
WHERE NOT p.exclude AND NOT s.exclude AND NOT e.exclude
"""


def _previous_view_sql() -> str:
    """The view as revision 3b8e4f1a6c27 froze it (what the revisions since kept)."""
    path = next(Path(__file__).parent.glob("*_3b8e4f1a6c27_*.py"))
    spec = importlib.util.spec_from_file_location("revision_3b8e4f1a6c27", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return str(module.VIEW_WITH_POSTERIOR)


def upgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    op.execute(VIEW_PUBLISHED_GRADE)


def downgrade() -> None:
    op.execute("DROP VIEW IF EXISTS photoshape_candidate")
    op.execute(_previous_view_sql())
