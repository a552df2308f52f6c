"""One evidence builder: every caller that ranks a classifier's regions ranks them the same way."""

from __future__ import annotations

import json
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest

from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.classify.evidence import ClassifierEvidence, min_region_fraction
from photoshape_flow.classify.ranking import RankingPolicy

MATERIALS = (10, 11, 12, 13)
SUBSTANCES = ("wood", "wood", "metal", "fabric")
LABS = np.array([[40.0, 20.0, 30.0], [60.0, 10.0, 20.0], [70.0, 0.0, 0.0], [50.0, -10.0, -10.0]])
SIGMA = 20.0
HEAD_SUBSTANCES = np.array([0.05, 0.4, 0.1, 0.3, 0.1, 0.05], np.float32)  # [background, *vocab.SUBSTANCES]


class FakeClassifier:
    """Both heads' outputs depend on the region's size only, so every caller's batching gives the same rows."""

    materials = list(MATERIALS)
    material_substances = list(SUBSTANCES)

    def predict(self, image: np.ndarray, masks: list[np.ndarray], crop: str = "image") -> tuple[np.ndarray, np.ndarray]:
        rows = [[0.1, 0.2, 0.3, 0.15, 0.25] if mask.sum() >= 100 else [0.05, 0.5, 0.1, 0.3, 0.05] for mask in masks]
        return np.array(rows, np.float32), np.tile(HEAD_SUBSTANCES, (len(masks), 1))

    def policy(self, min_region_fraction: float = 0.0, substance_first: bool = True,
               enabled: Any = None) -> RankingPolicy:
        return RankingPolicy(MATERIALS, SUBSTANCES, substance_first, min_region_fraction, enabled)


def scene() -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """A 100 px photo, its material-id map and masks: 10 over 4% of it, 12 over 0.25% (below 0.5%)."""
    image = np.full((100, 100, 3), 255, np.uint8)
    ids = np.zeros((100, 100), np.int32)
    ids[10:30, 10:30], image[10:30, 10:30] = 10, (120, 80, 50)
    ids[60:65, 60:65], image[60:65, 60:65] = 12, (170, 170, 170)
    return image, ids, {10: ids == 10, 12: ids == 12}


def test_a_config_without_the_smallest_region_takes_the_training_default() -> None:
    assert min_region_fraction({}) == min_region_fraction(None) == ClassifierConfig.min_region_fraction == 0.005
    assert min_region_fraction({"min_region_fraction": 0.02}) == 0.02
    evidence = ClassifierEvidence.for_classifier(FakeClassifier(), {"frame_object": False})
    assert evidence.policy.min_region_fraction == 0.005 and evidence.policy.enabled is None


def test_the_former_callers_rank_a_region_alike(tmp_path: Path, settings_env: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    from typer import Typer
    from typer.testing import CliRunner

    import photoshape_flow.classify.dataset as dataset
    import photoshape_flow.db.session as db_session
    import photoshape_flow.fitting.calibration as fit_calibration
    import photoshape_flow.networks.classifiers as classifiers
    import photoshape_flow.networks.evidence as evidence
    import photoshape_flow.recognition.calibration as calibration
    from photoshape_flow.cli import retrieve_cmd
    from photoshape_flow.recognition.part_evidence import PartInput, PartSubstanceView, rank_part

    image, ids, masks = scene()
    model, config, k = FakeClassifier(), {"architecture": "fake"}, 4  # a row config without min_region_fraction
    row = SimpleNamespace(id=1, name="fake", architecture="fake", config=config, checkpoint_blob="x")

    @contextmanager
    def no_database(*_: Any, **__: Any) -> Any:
        yield SimpleNamespace(get=lambda *_: row, execute=lambda *_: [])

    for module in (classifiers, fit_calibration):  # `retrieve` finds it in networks.classifiers
        monkeypatch.setattr(module, "load_material_classifier", lambda *_, **__: (row, model))
    monkeypatch.setattr(evidence, "stored_color_prior", lambda *_: (LABS, SIGMA))  # every ranker's evidence
    monkeypatch.setattr(fit_calibration, "session_scope", no_database)
    monkeypatch.setattr(db_session, "session_scope", no_database)
    monkeypatch.setattr(retrieve_cmd, "require_database", lambda: None)
    for module in (dataset, calibration):  # the posterior check reads renders with these
        monkeypatch.setattr(module, "load_rgb", lambda _: image)
        monkeypatch.setattr(module, "load_label_map", lambda _: ids)
    built = ClassifierEvidence.for_classifier(model, config, enabled=frozenset(MATERIALS), color_prior=(LABS, SIGMA))

    # the inference stage (its RankingContext builds `built` from the classifier row the same way)
    ctx = SimpleNamespace(method="classifier", evidence=built, top_k=k, substance_weights=lambda _: HEAD_SUBSTANCES)
    inference = {}
    for material, mask in masks.items():
        item = PartInput(SimpleNamespace(id=material), mask, PartSubstanceView(None, {}, True))
        batch = {material: tuple(a[0] for a in model.predict(image, [mask]))}
        inference[material] = [(r.material_id, r.score, r.posterior) for r in rank_part(ctx, image, ids > 0, item, 1,
                                                                                        batch)]
        assert (item.color is not None) and item.head is (material == 10)
    # the fit calibration's RenderRanker
    fit_ctx = SimpleNamespace(classifier=row, cfg=SimpleNamespace(top_k=k), store=None,
                              material_substance=dict(zip(MATERIALS, SUBSTANCES, strict=True)))
    ranker = fit_calibration.RenderRanker(fit_ctx, SimpleNamespace(torch_threads=1, resolved_database_url="unused"))
    fit = {material: [(r.material_id, r.score) for r in rows] for material, rows in ranker.rank(image, masks).items()}
    # `photoshape retrieve`
    cv2.imwrite(str(tmp_path / "photo.png"), image[..., ::-1])
    args = ["retrieve", str(tmp_path / "photo.png"), "--top", str(k), "--json"]
    for material, mask in masks.items():
        cv2.imwrite(str(tmp_path / f"{material}.png"), mask.astype(np.uint8) * 255)
        args += ["-m", str(tmp_path / f"{material}.png")]
    app = Typer()
    retrieve_cmd.register(app)
    app.command("unused")(lambda: None)
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    regions = json.loads(result.stdout[result.stdout.index("{"):])["regions"]
    retrieve = {material: [(r["material_id"], r["score"], r["posterior"]) for r in region["materials"]]
                for material, region in zip(masks, regions, strict=True)}
    # the training stage's posterior check (regions below the smallest training region are not checked)
    posteriors, _ = calibration._ranked_regions(model, ClassifierEvidence.for_classifier(
        model, config, enabled=frozenset(MATERIALS), color_prior=(LABS, SIGMA)), [SimpleNamespace(
            image="i", material_map="m", key="k")], framed=False)

    for material in masks:
        assert inference[material] == retrieve[material]  # the same numbers, not just the same order
        assert fit[material] == [(m, s) for m, s, _ in inference[material]]
    assert posteriors == pytest.approx([inference[10][0][2]])
    # the small region was ranked without the head by every caller (0.0025 < 0.005): substance x colour only
    assert built.rank(built.region(None, HEAD_SUBSTANCES, image, masks[12]), k).materials[0].material_id == \
        inference[12][0][0]
