"""`photoshape eval --groundtruth FILE` on the tiny demo, on SQLite and PostgreSQL: a user's file with
bad entries (each reported and skipped), one entry without a mask (scored by part names), figures
tagged with the file's hash, the file registered as the next default, a headline before the table.

The pipeline's own outputs are replaced by an oracle written straight into the database (pairs of
each photo's true shape aligned by its ground-truth labels, "ours" given the true materials, the
colour baseline a material of another substance), so every expected figure is known exactly and
the test takes seconds instead of a pipeline run.
"""

from __future__ import annotations

import copy
import hashlib
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import sqlalchemy as sa
from tests.conftest import ingest_tiny_demo
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.scoring import truths
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore

runner = CliRunner()


def flat(text: str) -> str:
    """Output without whitespace: rich wraps long lines and table cells."""
    return "".join(text.split())


def users_file(demo: Path, out: Path) -> tuple[Path, list[str]]:
    """The demo's ground truth edited as a user might get it wrong; returns it and the skipped names.

    ex_0000: mask removed (scored by part names); ex_0002, ex_0003 (a held-out shape): unchanged;
    ex_0004: an unknown material; ex_0005: no mask and a part left out; ex_0001: a held-out shape no
    longer declared outside the collection; plus a photo never ingested and an entry of wrong types.
    """
    data = json.loads((demo / "groundtruth.json").read_text())
    by_id = {e["source_id"]: e for e in data["exemplars"]}
    for e in data["exemplars"]:
        e["mask"]["path"] = str(demo / e["mask"]["path"])  # the copy lives elsewhere: absolute paths
    del by_id["ex_0000"]["mask"]
    next(iter(by_id["ex_0004"]["parts"].values()))["material"] = "unobtainium"
    del by_id["ex_0005"]["mask"]
    by_id["ex_0005"]["parts"].pop(sorted(by_id["ex_0005"]["parts"])[0])
    del by_id["ex_0001"]["in_collection"]
    data["exemplars"] += [dict(copy.deepcopy(by_id["ex_0002"]), source_id="ex_0999"), {"source_id": 5}]
    path = out / "my-truth.json"
    path.write_text(json.dumps(data))
    return path, ["ex_0004", "ex_0005", "ex_0001", "ex_0999", "exemplars[7]"]


def add_oracle(url: str, store: BlobStore, demo: Path) -> int:
    """Pairs of every in-collection photo with its true shape (see the module docstring); returns the
    number of parts the file's ex_0002 (the one good entry with a mask and a pair) labels."""
    gt = read_groundtruth_file(demo / "groundtruth.json")
    labelled = 0
    with session_scope(url) as session:
        shapes = {s.source_id: s for s in session.execute(sa.select(m.Shape)).scalars()}
        materials = {x.name: x for x in session.execute(sa.select(m.Material)).scalars()}
        session.add(m.Classifier(id=1, name="r18", kind="material", architecture="resnet18"))
        for exemplar_id, truth in match_groundtruth(session, gt).truths.items():
            if not truth.in_collection:
                continue
            shape = shapes[truth.shape]
            pair = m.Pair(shape_id=shape.id, exemplar_id=exemplar_id, rank=1, exemplar_rank=2, distance=0.0,
                          azimuth=0.0, elevation=0.0, fov=50.0, camera_distance=2.0)  # rank 2: no re-render
            session.add(pair)
            session.flush()
            labels, _, _ = truths.truth_labels(truth, session.get(m.Exemplar, exemplar_id))
            index = {p.name: p.index for p in shape.parts}
            part_map = np.array([0] + [index[name] for name in sorted(truth.parts)], np.uint8)[labels]
            blob = store.put_image(part_map)
            session.add(m.Alignment(pair_id=pair.id, method="flow-crf", coarse_blob=blob, flow_blob=blob,
                                    crf_blob=blob))
            if truth.stem == "ex_0002":
                labelled = len(np.unique(part_map[part_map > 0]))
            for part in shape.parts:
                true = truth.parts[part.name]
                other = min(n for n, x in materials.items() if x.substance != true.substance)
                session.add(m.PartSubstance(pair_id=pair.id, part_id=part.id, substance=true.substance))
                for method_key, name in (("classifier:1", true.material), ("color-match", other)):
                    session.add(m.Assignment(pair_id=pair.id, part_id=part.id, method=method_key.split(":")[0],
                                             method_key=method_key, rank=1, material_id=materials[name].id,
                                             substance=materials[name].substance))
    return labelled


@pytest.fixture
def migrated(any_db_url: str, settings_env: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """The settings point at `any_db_url`, migrated (SQLite and PostgreSQL)."""
    from photoshape_flow.config import get_settings
    from photoshape_flow.db import migrate
    from photoshape_flow.db.session import get_engine

    monkeypatch.setenv("PHOTOSHAPE_DATABASE_URL", any_db_url)
    get_settings.cache_clear()
    get_engine.cache_clear()
    migrate.upgrade(any_db_url)
    return any_db_url


@pytest.fixture
def oracle_db(migrated: str, tiny_demo: Path) -> int:
    from photoshape_flow.config import get_settings

    ingest_tiny_demo(tiny_demo, 96)
    return add_oracle(migrated, BlobStore(get_settings().blob_root), tiny_demo)


def figures(url: str, run: str) -> dict[tuple[str, str, str], tuple[float | None, int | None, str | None]]:
    with session_scope(url) as session:
        rows = session.execute(sa.select(m.Evaluation).where(m.Evaluation.run == run)).scalars()
        return {(r.stage, r.method, r.metric): (r.value, r.count, r.groundtruth_sha256) for r in rows}


def test_eval_groundtruth_scores_the_good_entries_and_names_each_bad_one(
    any_db_url: str, oracle_db: int, tiny_demo: Path, tmp_path: Path
) -> None:
    path, skipped = users_file(tiny_demo, tmp_path)
    stages = ["--stage", "substances", "--stage", "inference", "--stage", "fine-alignment"]
    result = runner.invoke(app, ["eval", "--groundtruth", str(path), "--run", "mine", *stages])
    assert result.exit_code == 0, result.output
    lines = [line for line in result.output.splitlines() if line.endswith("; skipped")]
    assert len(lines) == len(skipped), lines  # one line per bad entry, each naming it
    for name, reason in zip(skipped, ("unknown materials: unobtainium", "missing parts of shape demo-tiny/",
                                      "is not ingested (say \"in_collection\": false", "ex_0999 is not ingested",
                                      "source_id must be a non-empty string"), strict=True):
        assert any(name in line and reason in line for line in lines), (name, lines)
    assert re.search(r"^eval pairs x methods: \d+/\d+ \(100%\)", result.output, re.M), result.output  # progress
    out = flat(result.output)
    assert out.index("headline:ours") < out.index("ours(classifier1)") < out.index("color-match")
    assert out.index("color-match") < out.index("everyfigure")
    # the headline reads at 80 columns; every figure goes to the file it names, one line each
    named = re.search(r"^every figure \((\d+)\): (\S+)$", result.output, re.M)
    assert named, result.output
    headline = result.output[result.output.index("headline: "):named.start()].splitlines()
    assert all(len(line) <= 80 and "…" not in line for line in headline), headline  # nothing cut or wrapped
    assert any(re.match(r"color-match +0\.000 +0\.000 .* -1\.000 \[-1\.00,-1\.00\]$", line) for line in headline)
    text = Path(named.group(2)).read_text()
    assert Path(named.group(2)).parent.name == "evaluations" and Path(named.group(2)).name == "mine.txt"
    assert all(len(line) <= 80 for line in text.splitlines())
    assert "every figure" not in result.output.split(named.group(0))[1]  # the table itself is not printed
    assert re.search(r"^inference / classifier:1$", text, re.M)
    assert re.search(r"^  material_top1 +1\.0000 +\d+", text, re.M), text

    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    got = figures(any_db_url, "mine")
    parts = 3 + oracle_db  # ex_0000 by its 3 part names (no mask), ex_0002 by the pixels of each part
    assert got[("inference", "classifier:1", "material_top1")] == (1.0, parts, sha)
    assert got[("inference", "classifier:1", "material_top5")] == (1.0, parts, sha)
    assert got[("inference", "classifier:1", "substance_accuracy")] == (1.0, parts, sha)
    assert got[("inference", "color-match", "material_top1")] == (0.0, parts, sha)
    assert got[("inference", "color-match", "substance_accuracy")] == (0.0, parts, sha)
    assert got[("substances", "substance-network", "part_substance_accuracy")] == (1.0, parts, sha)
    # part-label accuracy only where a part mask is given: ex_0002's pair, not ex_0000's
    assert got[("fine-alignment", "flow-crf", "n_exact")][0] == 1.0
    assert got[("fine-alignment", "flow-crf", "accuracy_crf")][0] > 0.95
    with session_scope(any_db_url) as session:
        row = session.execute(sa.select(m.GroundTruthFileRow)).scalar_one()
        assert (row.path, row.sha256, row.entries, row.skipped) == (str(path.resolve()), sha, 3, len(skipped))

    # the next eval without a file scores against the registered one
    again = runner.invoke(app, ["eval", "--run", "again", "--stage", "substances"])
    assert again.exit_code == 0, again.output
    assert str(path) in flat(again.output)
    assert figures(any_db_url, "again")[("substances", "substance-network", "part_substance_accuracy")] == (
        1.0, parts, sha)


def test_eval_fails_in_one_line_on_a_foreign_file_or_when_nothing_matches(migrated: str, tmp_path: Path) -> None:
    nothing = runner.invoke(app, ["eval"])  # no file given, none registered, no demo under the data root
    assert nothing.exit_code == 1 and "passone(--groundtruthFILE" in flat(nothing.output), nothing.output
    cases: list[tuple[Any, str]] = [
        ({"version": 1, "exemplars": {}}, "a pre-format demo file"),
        ({"format": "photoshape-groundtruth", "version": 2, "exemplars": [{"source_id": "nobody", "shape": {
            "source_id": "x"}, "parts": {"seat": {"material": "m", "substance": "wood"}}}]},
         "no ingested exemplar matches"),
    ]
    for data, message in cases:
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(data))
        result = runner.invoke(app, ["eval", "--groundtruth", str(path)])
        assert result.exit_code == 1, result.output
        assert message.replace(" ", "") in flat(result.output)
        assert "Traceback" not in result.output
    with session_scope(migrated) as session:
        assert session.execute(sa.select(sa.func.count()).select_from(m.Evaluation)).scalar_one() == 0
