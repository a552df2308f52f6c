"""The whole photoshape-pipeline flow on the tiny demo, under Prefect's test harness."""

from __future__ import annotations

from pathlib import Path

import pytest
import sqlalchemy as sa
from tests.conftest import data_root_with_inbox
from tests.db.test_data_model_doc import doc_queries

pytestmark = [pytest.mark.prefect, pytest.mark.slow, pytest.mark.render]


def recoloured_materials(tmp_path: Path, demo: Path) -> list[Path]:
    """Folders of two new materials: recoloured copies of demo ones, named `new_*`."""
    import json
    import shutil

    import cv2

    folders = []
    for i, source in enumerate(sorted((demo / "materials").iterdir())[:2]):
        target = tmp_path / "new-materials" / f"new_{source.name}"
        shutil.copytree(source, target)
        sidecar = json.loads((target / "material.json").read_text())
        sidecar["name"] = f"new_{sidecar['name']}"
        (target / "material.json").write_text(json.dumps(sidecar))
        albedo = next(target.glob("albedo.*"))
        image = cv2.imread(str(albedo))
        cv2.imwrite(str(albedo), image[..., [1, 2, 0]] if i == 0 else 255 - image)
        folders.append(target)
    return folders


def test_pipeline_flow_runs_every_stage_on_tiny_demo(tiny_demo: Path, tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from photoshape_flow.flows.pipeline import photoshape_pipeline
    from prefect.testing.utilities import prefect_test_harness

    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db import models as m
    from photoshape_flow.db.session import get_engine, session_scope
    from photoshape_flow.pipeline.progress import rendering_progress
    from photoshape_flow.stages import stage_progress

    data_root = data_root_with_inbox(tmp_path / "data", tiny_demo)
    monkeypatch.setenv("PHOTOSHAPE_DATA_ROOT", str(data_root))
    monkeypatch.delenv("PHOTOSHAPE_DATABASE_URL", raising=False)
    get_settings.cache_clear()
    get_engine.cache_clear()
    migrate.upgrade()
    with prefect_test_harness(server_startup_timeout=120):
        result = photoshape_pipeline(profile="tiny")
        with session_scope() as session:  # what `photoshape status` shows after the finished run
            finished = stage_progress(session)
            render_outcomes = dict(session.execute(
                sa.select(m.Rendering.status, sa.func.count()).where(m.Rendering.kind == "training")
                .group_by(m.Rendering.status)).all())
            bootstrap_rejected = session.execute(sa.select(sa.func.count()).where(
                m.Rendering.kind == "bootstrap", m.Rendering.status == "rejected")).scalar_one()
            kinds = {r.kind: r for r in rendering_progress(session)}
        from prefect.client.orchestration import get_client

        async def artifacts():  # type: ignore[no-untyped-def]
            async with get_client() as client:
                return {a.key: a.data for a in await client.read_artifacts()}

        import asyncio

        data = asyncio.run(artifacts())
        keys = set(data)
    assert list(result["seconds"]) == ["ingest", "coarse-alignment", "fine-alignment", "substances",
                                       "training-renders", "training", "inference", "fit", "publish"]
    assert {"photoshape-run-summary", "photoshape-candidates", "fine-alignment-progress"} <= keys
    # the loops inside the tasks report their item counts too (the CLI's progress, as artifacts)
    assert data["fine-alignment-pairs-items"] == 100.0 and data["publish-pairs-items"] == 100.0, sorted(keys)
    # nothing is pending after a finished run: publish counts only pairs up to the tiny profile's max_rank
    assert {p.stage: p.pending for p in finished} == dict.fromkeys(result["seconds"], 0)
    renders = {p.stage: p for p in finished}["training-renders"]  # the training round's renders only
    assert renders.rejected == render_outcomes.get("rejected", 0)  # rejected renders are not failures
    assert renders.failed == sum(n for status, n in render_outcomes.items() if status not in ("ok", "rejected"))
    # the bootstrap round's renders under the stage that made them, rejections with their reasons
    assert (kinds["bootstrap"].stage, kinds["bootstrap"].rejected) == ("substances", bootstrap_rejected)
    assert bool(kinds["bootstrap"].reasons) == (bootstrap_rejected > 0)
    summary = str(data["photoshape-run-summary"])
    assert "| failed | rejected |" in summary and "Counts assume profile tiny (last run #" in summary
    assert "| bootstrap | substances |" in summary and "| why rejected |" in summary
    with session_scope() as session:
        progress = {p.stage: p for p in stage_progress(session)}
        candidates = session.execute(sa.text("SELECT COUNT(DISTINCT pair_id) FROM photoshape_candidate "
                                             "WHERE method = 'classifier'")).scalar_one()
        colour_ranked = session.execute(sa.text(
            "SELECT COUNT(*) FROM assignment WHERE method = 'classifier' AND NOT unobserved "
            "AND json_extract(params, '$.color_likelihood') IS NOT NULL")).scalar_one()
        network = session.execute(sa.select(m.Classifier).where(m.Classifier.kind == "substance")).scalar_one()
        # the documented query lists the published PhotoShapes of the tiny demo (whatever method publish uses)
        confident = session.execute(sa.text(doc_queries()[0])).all()
        posterior_sums = session.execute(sa.text(
            "SELECT SUM(posterior) FROM assignment WHERE method = 'classifier' GROUP BY pair_id, part_id")).scalars()
        material = session.execute(sa.select(m.Classifier).where(m.Classifier.kind == "material")).scalar_one()
        photoshape_renders = session.execute(
            sa.select(sa.func.count()).select_from(m.Rendering).where(m.Rendering.kind == "photoshape")
        ).scalar_one()
    for stage in ("coarse-alignment", "fine-alignment", "substances", "inference"):
        assert progress[stage].done > 0 and progress[stage].pending == 0, stage
    assert candidates > 0 and photoshape_renders > 0
    assert confident, "the documented query lists no published PhotoShape"
    assert all(0.0 < v <= 1.0 + 1e-9 for v in posterior_sums)
    assert 0.0 <= material.metrics["posterior_ece"] <= 1.0 and material.metrics["posterior_reliability"]["regions"] > 0
    assert colour_ranked > 0  # observed parts ranked with the colour likelihood fit on validation renders
    # the substance confidence's part-level temperature, fit on the network's validation renders
    assert network.metrics["part_temperature_parts"] >= 0 and "part_temperature" in network.metrics
    assert (data_root / "gallery" / "index.html").is_file()
    with session_scope() as session:  # the flow records its run as `photoshape run` does
        run = session.execute(sa.select(m.PipelineRun).where(m.PipelineRun.origin == "flow")).scalar_one()
        assert (run.profile_name, run.status, run.stages) == ("tiny", "ok", list(result["seconds"]))
        assert run.reports["fine-alignment"]["done"] > 0 and run.profile["publish"]["max_rank"] == 1

    get_settings.cache_clear()
    get_engine.cache_clear()
