"""SQL views. `photoshape_candidate`: pairs with their top-ranked assignment per part.

One row per (pair, part, method_key): filter on `method` (classifier or a baseline name) or on
`classifier_id`. `posterior` is the part's score normalised over all enabled materials (what a
threshold such as "every part at least 0.5" should use); `score` the raw product of experts.
Excluded pairs, shapes and exemplars are left out.
"""

from __future__ import annotations

CANDIDATE_VIEW = "photoshape_candidate"

CANDIDATE_VIEW_SQL = """
CREATE VIEW photoshape_candidate AS
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
    a.posterior     AS posterior,
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

DROP_CANDIDATE_VIEW_SQL = "DROP VIEW IF EXISTS photoshape_candidate"
