"""Stage "training": classifier rows from training renders, reuse, resume after a kill, fine-tune, retrieve."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
import typer
from tests.classify.regiondata import render_arrays
from typer.testing import CliRunner

from photoshape_flow.db.models import Classifier, Evaluation, Material, Rendering
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.networks.classifiers import load_material_classifier
from photoshape_flow.recognition import training as train_module  # run_training calls train_classifier from here
from photoshape_flow.recognition.training import run_training

TOY = {"oak": ("wood", (150, 90, 40)), "denim": ("fabric", (40, 60, 170)), "steel": ("metal", (120, 120, 130))}


def _add_materials(url: str, named: dict[str, tuple[str, tuple[int, int, int]]]) -> dict[int, tuple]:
    with session_scope(url) as session:
        ids = upsert(session, Material, [{"name": n, "substance": s} for n, (s, _) in named.items()], key=["name"])
    return dict(zip(ids, named.values(), strict=True))


def _add_renders(url: str, store, materials: dict[int, tuple], count: int, prefix: str, val_every: int = 4) -> None:
    rows = []
    for i in range(count):
        image, id_map = render_arrays(i, 48, materials, seed=len(prefix))
        rows.append({
            "kind": "training", "key": f"{prefix}/{i:04d}", "split": "val" if i % val_every == 0 else "train",
            "status": "ok", "params": {},
            "blobs": {"beauty": store.put_image(image), "material_ids": store.put_image(id_map)},
        })
    with session_scope(url) as session:
        upsert(session, Rendering, rows, key=["kind", "key"])


def _classifier(url: str, classifier_id: int) -> Classifier:
    with session_scope(url) as session:
        row = session.get(Classifier, classifier_id)
        session.expunge(row)
        return row


def test_training_writes_an_ok_classifier_with_table4_metrics_and_is_idempotent(db_url: str, store) -> None:
    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 10, "a")
    classifier_id = run_training("tiny")
    row = _classifier(db_url, classifier_id)
    assert row.status == "ok" and row.kind == "material" and row.architecture == "resnet18-w8"
    assert row.materials == [0, *sorted(materials)] and row.material_set_hash
    assert row.epoch == 2 and row.checkpoint_blob and store.exists(row.checkpoint_blob)
    # superseded per-epoch resume checkpoints are deleted; only the slim final one stays
    assert [r for r in store.iter_refs() if r.endswith(".pt")] == [row.checkpoint_blob]
    for key in ("mtl@1", "mtl@5", "sub@1", "sub-mtl@1"):
        assert 0.0 <= row.metrics[key] <= 1.0
    assert row.metrics["val_renderings"] == 3 and row.metrics["val_source"] == "split"
    assert len(row.metrics["history"]) == 2 and row.metrics["selected_epoch"] == 2  # tiny keeps the last
    with session_scope(db_url) as session:
        metrics = set(session.scalars(sa.select(Evaluation.metric).where(Evaluation.run == row.name)))
    assert metrics == {"mtl@1", "mtl@5", "sub@1", "sub-mtl@1"}

    assert run_training("tiny") == classifier_id  # same config, materials and data: reused
    with session_scope(db_url) as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(Classifier)) == 1

    _, classifier = load_material_classifier()
    assert classifier.materials == sorted(materials)


def test_killed_training_resumes_from_its_checkpoint(db_url: str, store, monkeypatch: pytest.MonkeyPatch) -> None:
    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 8, "a")
    real = train_module.train_classifier

    def killed_after_one_epoch(*args, **kwargs):  # type: ignore[no-untyped-def]
        real(*args, **kwargs, stop_after_epochs=1)
        raise RuntimeError("worker killed")

    monkeypatch.setattr(train_module, "train_classifier", killed_after_one_epoch)
    with pytest.raises(RuntimeError, match="killed"):
        run_training("tiny")
    with session_scope(db_url) as session:
        (row,) = session.scalars(sa.select(Classifier)).all()
        session.expunge(row)
    assert row.status == "failed" and "worker killed" in row.error and row.epoch == 1
    first_epoch = row.metrics["history"][0]

    monkeypatch.setattr(train_module, "train_classifier", real)
    assert run_training("tiny") == row.id
    done = _classifier(db_url, row.id)
    assert done.status == "ok" and done.epoch == 2 and done.error is None
    assert done.metrics["history"][0] == first_epoch  # continued, not restarted


def test_the_stored_model_is_the_best_validation_epoch(db_url: str, store) -> None:
    from photoshape_flow.classify import checkpoint as ckpt

    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 10, "a")
    classifier_id = run_training("tiny", overrides={"epochs": 4, "select_metric": "mtl@1"})
    row = _classifier(db_url, classifier_id)
    history = row.metrics["history"]
    best = max(history, key=lambda h: h["mtl@1"])  # the first of equals, as the loop keeps it
    assert row.metrics["selected_epoch"] == best["epoch"] and row.metrics["mtl@1"] == best["mtl@1"]
    assert row.epoch == 4
    stored = ckpt.load(store.read_bytes(row.checkpoint_blob))
    assert stored["selected_epoch"] == best["epoch"] and "best" not in stored and "optimizer" not in stored


def test_new_materials_fine_tune_the_previous_classifier(db_url: str, store) -> None:
    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 8, "a")
    first = run_training("tiny")
    new = _add_materials(db_url, {"walnut": ("wood", (90, 50, 20))})
    _add_renders(db_url, store, {**materials, **new}, 8, "bb")
    second = run_training("tiny")
    assert second != first
    row = _classifier(db_url, second)
    assert row.parent_id == first and row.config["finetune"] is True
    assert row.epoch == 1  # tiny's finetune_epochs
    assert row.materials == [0, *sorted(materials), *new]
    assert row.metrics["finetuned_from"] == first


def test_retrieve_cli_ranks_materials_for_a_region(db_url: str, store, tmp_path: Path) -> None:
    from photoshape_flow.cli import retrieve_cmd

    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 6, "a")
    classifier_id = run_training("tiny")
    image, id_map = render_arrays(99, 64, materials)
    cv2.imwrite(str(tmp_path / "photo.png"), image[..., ::-1])
    region = (id_map == id_map.max()).astype(np.uint8) * 255
    cv2.imwrite(str(tmp_path / "mask.png"), region)
    cv2.imwrite(str(tmp_path / "empty.png"), np.zeros_like(region))

    app = typer.Typer()
    app.callback()(lambda: None)
    retrieve_cmd.register(app)
    runner = CliRunner()
    result = runner.invoke(app, ["retrieve", str(tmp_path / "photo.png"), "--mask", str(tmp_path / "mask.png"),
                                 "--top", "2", "--json"])
    assert result.exit_code == 0, (result.output, result.exception)
    import json

    payload = json.loads(result.output)
    assert payload["classifier"]["id"] == classifier_id
    ranked = payload["regions"][0]["materials"]
    assert len(ranked) == 2 and {r["name"] for r in ranked} <= set(TOY)
    assert ranked[0]["score"] >= ranked[1]["score"]
    assert 0.0 < ranked[1]["posterior"] and ranked[0]["posterior"] + ranked[1]["posterior"] <= 1.0 + 1e-9
    assert payload["color_sigma"] is None  # the materials have no colour yet: no colour likelihood

    # with the materials' colours known, the training stage's calibration fits sigma on the val renders;
    # retrieve reads it, and the colour likelihood puts the material drawn in the region's colour first
    from photoshape_flow.config import get_settings
    from photoshape_flow.recognition.calibration import calibrate

    with session_scope(db_url) as session:
        for mid, (_, colour) in materials.items():
            session.execute(sa.update(Material).where(Material.id == mid)
                            .values(params={"albedo": [c / 255 for c in colour]}))
    args = ["retrieve", str(tmp_path / "photo.png"), "--mask", str(tmp_path / "mask.png"), "--json"]
    assert json.loads(runner.invoke(app, args).output)["color_sigma"] is None  # not calibrated yet: not fitted
    calibration = calibrate(get_settings(), classifier_id)
    fitted = calibration["color_sigma"]
    # the calibration check: the posterior's reliability on the validation renders' regions
    check = calibration["posterior"]
    assert check["regions"] > 0 and 0.0 <= check["ece"] <= 1.0 and 0.0 < check["mean_posterior"] <= 1.0
    assert sum(b["count"] for b in check["bins"]) == check["regions"]
    coloured = json.loads(runner.invoke(app, args).output)
    assert 1.0 <= coloured["color_sigma"] < 20 and coloured["color_sigma"] == pytest.approx(fitted)
    assert coloured["regions"][0]["materials"][0]["material_id"] == int(id_map.max())
    # the fitted sigma is cached on the classifier row, keyed by the renders and material colours
    with session_scope(db_url) as session:
        cached = dict(session.get(Classifier, classifier_id).metrics)
    assert cached["color_sigma"] == pytest.approx(coloured["color_sigma"])
    assert cached["posterior_ece"] == check["ece"] and cached["posterior_reliability"] == check
    assert calibrate(get_settings(), classifier_id)["color_sigma"] == fitted  # cached: not refit
    with session_scope(db_url) as session:
        assert session.get(Classifier, classifier_id).metrics["color_sigma_key"] == cached["color_sigma_key"]
        first = min(materials)
        session.execute(sa.update(Material).where(Material.id == first).values(params={"albedo": [0.9, 0.9, 0.1]}))
    calibrate(get_settings(), classifier_id)
    with session_scope(db_url) as session:  # a material's colour changed: refit under a new key
        assert session.get(Classifier, classifier_id).metrics["color_sigma_key"] != cached["color_sigma_key"]
    plain = json.loads(runner.invoke(app, [*args, "--no-color-prior"]).output)
    assert plain["color_sigma"] is None
    table = runner.invoke(app, ["retrieve", str(tmp_path / "photo.png"), "-m", str(tmp_path / "mask.png")])
    assert table.exit_code == 0 and "substance" in table.output
    bad = runner.invoke(app, ["retrieve", str(tmp_path / "photo.png"), "-m", str(tmp_path / "empty.png")])
    assert bad.exit_code == 1 and "empty" in bad.output
    missing = runner.invoke(app, ["retrieve", str(tmp_path / "photo.png"), "-m", str(tmp_path / "mask.png"),
                                  "--classifier", "999"])
    assert missing.exit_code == 1 and "999" in missing.output


def test_validation_held_out_by_key_when_no_rendering_is_val(db_url: str, store) -> None:
    from photoshape_flow.recognition.training import training_data

    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 40, "a", val_every=10**6)  # only index 0 is "val"
    with session_scope(db_url) as session:
        session.execute(sa.update(Rendering).values(split="train"))
        data = training_data(session, store, val_fraction=0.25)
        again = training_data(session, store, val_fraction=0.25)
    assert data.val_source == "held-out" and 0 < len(data.val) < len(data.train)
    assert data == again  # stable: same items, same hash


def test_no_training_renders_fails_the_row_with_a_reason(db_url: str, store) -> None:
    _add_materials(db_url, TOY)
    with pytest.raises(ValueError, match="training-renders"):
        run_training("tiny")
    with session_scope(db_url) as session:
        (row,) = session.scalars(sa.select(Classifier)).all()
        assert row.status == "failed" and "training regions" in row.error


def test_the_part_recogniser_trains_through_the_stage_and_records_its_weights(db_url: str, store) -> None:
    """The recogniser (D53) is one config field away: same stage, same row, the weights' sha256 on it."""
    from photoshape_flow.classify.backbone import weights_sha256

    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 8, "a")
    classifier_id = run_training("tiny", overrides={"arch": "efficientnet-lite0", "crop_size": 32})
    row = _classifier(db_url, classifier_id)
    assert row.status == "ok" and row.architecture == "efficientnet-lite0-part32"
    assert row.config["backbone_sha256"] == weights_sha256("efficientnet-lite0")
    _, classifier = load_material_classifier(classifier_id)
    assert type(classifier.model).__name__ == "PartRecognizer" and not classifier.model.training
    # the ResNet on the same data is another network (the architecture is in the hash), not a reuse
    assert run_training("tiny") != classifier_id


def test_the_descriptor_stores_each_materials_vector_and_a_kill_while_computing_them_resumes_the_same(
        db_url: str, store, monkeypatch: pytest.MonkeyPatch) -> None:
    """The descriptor (D61): trained by the same stage, its material vectors computed from the training
    renders through the selected weights and stored in the checkpoint; killed while computing them,
    the next run resumes the row and stores the same weights and vectors."""
    import torch

    from photoshape_flow.classify import checkpoint as ckpt
    from photoshape_flow.classify.dataset import RegionDataset, find_regions
    from photoshape_flow.classify.descriptor import fit_prototypes
    from photoshape_flow.classify.train import select_best

    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 8, "a")
    overrides = {"arch": "efficientnet-lite0", "crop_size": 32, "head": "descriptor"}
    real = train_module.fit_prototypes

    def killed(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise RuntimeError("worker killed while computing material vectors")

    monkeypatch.setattr(train_module, "fit_prototypes", killed)
    with pytest.raises(RuntimeError, match="killed"):
        run_training("tiny", overrides=overrides)
    with session_scope(db_url) as session:
        (row,) = session.scalars(sa.select(Classifier)).all()
        session.expunge(row)
    assert row.status == "failed" and row.epoch == 2  # every epoch saved; the vectors were not
    trained = select_best(ckpt.slim(ckpt.load(store.read_bytes(row.checkpoint_blob))))["model"]

    monkeypatch.setattr(train_module, "fit_prototypes", real)
    assert run_training("tiny", overrides=overrides) == row.id
    done = _classifier(db_url, row.id)
    assert done.status == "ok" and done.architecture == "efficientnet-lite0-desc32"
    assert done.metrics["history"] == row.metrics["history"]  # resumed, not retrained
    stored = ckpt.load(store.read_bytes(done.checkpoint_blob))["model"]
    assert all(torch.equal(stored[k], v) for k, v in trained.items() if k not in ("prototypes", "has_prototypes"))
    assert bool(stored["has_prototypes"])
    _, classifier = load_material_classifier(row.id)
    model = classifier.model
    assert type(model).__name__ == "MaterialDescriptor" and not model.training
    # the stored vectors are those of the selected weights over the training renders, recomputed
    from photoshape_flow.recognition.material_sets import material_set
    from photoshape_flow.recognition.training import training_data

    with session_scope(db_url) as session:
        data, listed = training_data(session, store), material_set(session)
    renders = RegionDataset(data.train, find_regions(data.train, listed.ids, listed.substance_of), 32)
    fit_prototypes(model, renders)
    assert torch.allclose(model.prototypes, stored["prototypes"], atol=1e-6)


def test_a_descriptor_reads_new_materials_from_their_renders_without_training(db_url: str, store) -> None:
    """`finetune_epochs=0`: the grown descriptor keeps its parent's weights; the new material's vector is
    the mean descriptor of its rendered parts (MatCLIP's point: a material added later, no retrain)."""
    import torch

    from photoshape_flow.classify import checkpoint as ckpt
    from photoshape_flow.classify.dataset import RegionDataset, find_regions
    from photoshape_flow.recognition.material_sets import material_set
    from photoshape_flow.recognition.training import training_data

    overrides = {"arch": "efficientnet-lite0", "crop_size": 32, "head": "descriptor", "finetune_epochs": 0}
    materials = _add_materials(db_url, TOY)
    _add_renders(db_url, store, materials, 8, "a")
    first = run_training("tiny", overrides=overrides)
    new = _add_materials(db_url, {"walnut": ("wood", (90, 50, 20))})
    _add_renders(db_url, store, {**materials, **new}, 8, "bb")
    second = run_training("tiny", overrides=overrides)
    row, parent = _classifier(db_url, second), _classifier(db_url, first)
    assert row.status == "ok" and row.parent_id == first and row.epoch == 0 and row.metrics["history"] == []
    grown = ckpt.load(store.read_bytes(row.checkpoint_blob))["model"]
    trained = ckpt.load(store.read_bytes(parent.checkpoint_blob))["model"]
    kept = [k for k in trained if not k.startswith("fc_material") and k not in ("prototypes", "has_prototypes")]
    assert kept and all(torch.equal(grown[k], trained[k]) for k in kept)  # not trained: same weights
    _, classifier = load_material_classifier(second)
    model = classifier.model
    (walnut,) = new
    with session_scope(db_url) as session:
        data, listed = training_data(session, store), material_set(session)
    label = listed.ids.index(walnut) + 1
    examples = [e for e in find_regions(data.train, listed.ids, listed.substance_of) if e.label == label]
    x = torch.stack([RegionDataset(data.train, examples, 32)[i][0] for i in range(len(examples))])
    with torch.no_grad():
        expected = torch.nn.functional.normalize(model.describe(x).mean(0), dim=0)
    assert torch.allclose(model.prototypes[label - 1], expected, atol=1e-5)
    with pytest.raises(ValueError, match="needs head 'descriptor'"):
        run_training("tiny", overrides={"finetune_epochs": 0})
