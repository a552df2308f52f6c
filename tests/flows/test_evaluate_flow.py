"""The `evaluate` flow fans the inference figures out over exemplar batches and pools them once:
the same figures and intervals as one `photoshape eval` over every exemplar."""

from __future__ import annotations

from pathlib import Path

import pytest
import sqlalchemy as sa
from tests.pipeline.test_evaluate import ALL_SEAT, PART_MAP, TOP_HALF, TRUTH, add_assignments, build_scene

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.store import BlobStore

pytestmark = [pytest.mark.prefect]


def stored(url: str, run: str) -> dict[tuple[str, str, str], tuple[float | None, int | None, float | None]]:
    with session_scope(url) as session:
        rows = session.execute(sa.select(m.Evaluation).where(m.Evaluation.run == run)).scalars()
        return {(r.stage, r.method, r.metric): (r.value, r.count, r.ci_low, r.ci_high) for r in rows}


def test_batched_evaluation_equals_one_pass(db_url: str, store: BlobStore, tmp_path: Path) -> None:
    from photoshape_flow.flows.evaluate import evaluate
    from prefect.testing.utilities import prefect_test_harness

    from photoshape_flow.scoring.evaluate import evaluation_batches, run_evaluation

    made = build_scene(db_url, store, tmp_path / "demo", {"photo": TRUTH, "photo2": ALL_SEAT},
                       {"photo": PART_MAP, "photo2": TOP_HALF})
    add_assignments(db_url, made, "photo", "classifier:1", {1: ["oak"], 2: ["blue_leather"], 3: ["oak"]})
    add_assignments(db_url, made, "photo2", "classifier:1", {1: ["red_leather"]})
    add_assignments(db_url, made, "photo", "color-match", {1: ["red_leather"], 2: ["blue_leather"], 3: ["oak"]})
    add_assignments(db_url, made, "photo2", "color-match", {1: ["oak"]})
    assert [len(b) for b in evaluation_batches(made.groundtruth, 1)] == [1, 1]
    stages = ["substances", "inference"]
    run_evaluation(made.groundtruth, "whole", stages=stages, rerender_max_pairs=0)
    with prefect_test_harness(server_startup_timeout=120):
        result = evaluate(groundtruth=str(made.groundtruth), run="batched", batch_size=1, stages=stages)
    whole, batched = stored(db_url, "whole"), stored(db_url, "batched")
    assert batched == whole
    top1 = batched[("inference", "classifier:1", "material_top1")]
    assert top1[0] == pytest.approx(2 / 4) and top1[2] is not None and top1[2] < top1[3]
    assert ("inference", "color-match", "material_top1_vs_ours") in batched
    assert result["headline"][0]["method"] == "ours (classifier 1)"
