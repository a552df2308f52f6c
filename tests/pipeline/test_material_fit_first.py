"""A material ingested after the classifier wins parts through `fit`, without a retrain.

The tiny demo's in-collection exemplars are planted as pairs at the true camera with the true part map
(`tests.pipeline.aligned.plant_true_pair`) and a planted classifier ranking that is always wrong; the
material that most in-collection parts truly wear (fabric_blue_twill when written: the demo's only
blue material) is removed before the first fit, so that fit cannot choose it. Then it is
ingested again for real, and the material-added re-run (`photoshape new-materials`, run as a user runs it) must
re-fit the affected pairs only, let the new material win parts it truly covers, publish them with
fit (publish's default method, D46), and report counts that match the rows.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest
import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.store import BlobStore

pytestmark = [pytest.mark.slow, pytest.mark.render]


def _plant(tiny_demo: Path, db_url: str, store: BlobStore) -> tuple[dict[tuple[int, int], str], Path]:
    """Pairs and a planted ranking without the material most in-collection parts wear; (pair, part) ->
    true material name, and the held-out material's folder.

    Matching the ground truth needs every material it names, so the demo is ingested whole, matched,
    and the held-out material's row removed before anything uses it: as if it had never been ingested.
    """
    import json

    from tests.conftest import ingest_tiny_demo
    from tests.pipeline.aligned import plant_ranking, plant_true_pair

    from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
    from photoshape_flow.ingest.ingest import ingest_envmaps
    from photoshape_flow.scoring.groundtruth_match import match_groundtruth

    gt = read_groundtruth_file(tiny_demo / "groundtruth.json")
    held_out, _ = Counter(p.material for e in gt.entries if e.in_collection for p in e.parts.values()).most_common(1)[0]
    (folder,) = [d for d in (tiny_demo / "materials").iterdir()
                 if json.loads((d / "material.json").read_text())["name"] == held_out]
    ingest_tiny_demo(tiny_demo, exemplar_size=64)
    ingest_envmaps(sorted((tiny_demo / "envmaps").glob("studio*")), isolate=False)
    truth_of: dict[tuple[int, int], str] = {}
    with session_scope(db_url) as session:
        matched = match_groundtruth(session, gt, "demo-tiny")
        session.delete(session.execute(sa.select(m.Material).where(m.Material.name == held_out)).scalar_one())
        session.flush()
        shapes = {s.source_id: s for s in session.execute(sa.select(m.Shape)).scalars()}
        materials = list(session.execute(sa.select(m.Material).order_by(m.Material.id)).scalars())
        classifier = m.Classifier(name="planted", kind="material", architecture="none", status="ok",
                                  checkpoint_blob="planted", materials=[x.id for x in materials])
        session.add(classifier)
        session.flush()
        for exemplar_id, truth in matched.truths.items():
            if not truth.in_collection:
                continue
            shape = shapes[truth.shape]
            pair = plant_true_pair(session, store, shape, exemplar_id, truth)
            for part in shape.parts:
                true = truth.parts[part.name]
                others = [x for x in materials if x.substance != true.substance]  # the ranking is always wrong
                planted = [others[(part.index + k) % len(others)] for k in (0, 2, 4)]
                plant_ranking(session, pair, part, classifier, planted)
                truth_of[(pair.id, part.id)] = true.material
    return truth_of, folder


def _first_fit(url: str) -> dict[tuple[int, int], int]:
    with session_scope(url) as session:
        return {(p, part): mid for p, part, mid in session.execute(
            sa.select(m.Assignment.pair_id, m.Assignment.part_id, m.Assignment.material_id)
            .where(m.Assignment.method == "fit", m.Assignment.rank == 1))}


def test_a_new_material_wins_parts_through_fit_without_a_retrain(tiny_demo: Path, db_url: str,
                                                                 store: BlobStore) -> None:
    from typer.testing import CliRunner

    from photoshape_flow.cli import app
    from photoshape_flow.ingest.ingest import ingest_materials
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.publish.photoshapes import assignment_set_keys
    from photoshape_flow.stages import REGISTRY, StageContext, run_all
    from photoshape_flow.stages.new_materials import plan_material_rerun

    truth_of, held_out = _plant(tiny_demo, db_url, store)
    # the collection's last run: fit, at the tiny profile (the re-run inherits it, publish.method=fit included)
    (fitted,) = run_all(resolve_profile("tiny"), StageContext.create(), names=["fit"])
    assert fitted.done == len({p for p, _ in truth_of})
    before = _first_fit(db_url)
    (new_id,) = ingest_materials([held_out], source="demo-tiny", previews=False).added
    with session_scope(db_url) as session:
        new_name = session.get(m.Material, new_id).name
        classifiers = session.execute(sa.select(sa.func.count()).select_from(m.Classifier)).scalar_one()
        rerun = plan_material_rerun(session, "tiny", [], renders_per_material=6, registry=REGISTRY)
    assert rerun.new_ids == [new_id] and rerun.stages == ["fit", "publish"]
    assert set(rerun.pairs) == {p for p, _ in truth_of}  # every planted pair has an observed part

    result = CliRunner().invoke(app, ["new-materials", "--renders-per-material", "6"])
    assert result.exit_code == 0, result.output

    after = _first_fit(db_url)
    won = {key for key, mid in after.items() if mid == new_id}
    with session_scope(db_url) as session:
        observed = sum(params["fit"]["source"] != "ranking-only" for params in session.execute(
            sa.select(m.Assignment.params).where(m.Assignment.method == "fit", m.Assignment.rank == 1)).scalars())
        assert session.execute(sa.select(sa.func.count()).select_from(m.Classifier)).scalar_one() == classifiers
        assert not session.execute(sa.select(m.Rendering.id).where(m.Rendering.kind.in_(("training", "bootstrap")))
                                   ).first()  # nothing retrained, no training data made
        run = session.execute(sa.select(m.PipelineRun).where(m.PipelineRun.origin == "new-materials")).scalar_one()
        fit_key = rerun.fit_key
        published = dict(session.execute(sa.select(m.Rendering.pair_id, m.Rendering.params).where(
            m.Rendering.kind == "photoshape", m.Rendering.status == "ok",
            m.Rendering.key.like(f"%/{fit_key}/exemplar"))).all())
        keys = assignment_set_keys(session, [(p, fit_key) for p in published])
    # the new material wins parts it truly covers, through fit alone
    assert won and all(truth_of[key] == new_name for key in won), (won, new_name)
    changes = run.reports["fit"]["details"]["changes"]
    assert changes == {"parts": len(after), "grown": observed,  # it joined every observed part's candidates
                       "changed": sum(after[key] != before.get(key) for key in after), "won_by_new": len(won)}
    assert changes["changed"] >= len(won)
    assert (run.profile_name, run.profile["publish"]["method"], run.status) == ("tiny", "fit", "ok")
    assert run.stages == ["fit", "publish"] and run.reports["fit"]["done"] == len(rerun.pairs)
    row = re.search(r"parts changed \(fit:\d+\)\s*\n(?:.*\n){3}\W*(\d+)\W+(\d+)\W+(\d+)\W+(\d+)", result.output)
    assert row and [int(x) for x in row.groups()] == list(changes.values()), result.output
    # publish's default method, fit: the pairs whose parts the new material won are published with fit's rows
    assert {p for p, _ in won} <= set(published)
    for pair_id, params in published.items():
        assert params["assignment_set"] == keys[(pair_id, fit_key)]
