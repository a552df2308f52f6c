"""SQL views. `photoshape_candidate`: pairs with their top-ranked assignment per part.

One row per (pair, part, method_key), as the latest migration (c4d1a9e05b73) creates it: the shape's
and exemplar's names, `method` (classifier, fit or a baseline name), `published` (publish rendered
this PhotoShape: what the gallery's index lists, whatever `publish.method` is), `grade` (the newest
grade of this pair's PhotoShape of this method key), per part `confidence` (the posterior, else the
method's own score) and `posterior`, and `score`, the gallery's: the mean confidence over the parts
seen in the exemplar (all parts when none was), the same on every row of the PhotoShape;
`ranking_score` is the raw product of experts. Excluded pairs, shapes and exemplars are left out.
"""

from __future__ import annotations

CANDIDATE_VIEW = "photoshape_candidate"

CANDIDATE_VIEW_SQL = """
CREATE VIEW photoshape_candidate AS
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

DROP_CANDIDATE_VIEW_SQL = "DROP VIEW IF EXISTS photoshape_candidate"
