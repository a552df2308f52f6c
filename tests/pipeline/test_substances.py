"""Substances stage: bootstrap renders -> substance network -> PartSubstance rows, idempotent."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import sqlalchemy as sa
from tests.synth.collection import seed_collection

from photoshape_flow.classify.substance_configs import get_config
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.recognition.substances import run_substances
from photoshape_flow.vocab import SUBSTANCE_LABELS, SUBSTANCES

EXEMPLAR = 48


def _count(url: str, model: type) -> int:
    with session_scope(url) as session:
        return int(session.execute(sa.select(sa.func.count()).select_from(model)).scalar_one())


def _add_alignments(url: str, store, col) -> int:  # type: ignore[no-untyped-def]
    """Exemplars rendered from each pair's camera and their exact part maps as flow-crf alignments.

    The first pair's map loses its legs (as if the photo cropped them): that part must come out
    unobserved. Returns the part id of those legs.
    """
    from photoshape_flow.geometry.mesh import ShapeMesh
    from photoshape_flow.render import Camera, EnvmapSpec, MaterialSpec
    from photoshape_flow.render.renderer import Renderer

    renderer = Renderer(resolve=store.resolve)
    hidden_part = -1
    with session_scope(url) as session:
        envmap = session.get(m.Envmap, next(iter(col.envmaps)))
        for n, (pair_id, shape_id) in enumerate(sorted(col.pairs.items())):
            pair = session.get(m.Pair, pair_id)
            mesh = ShapeMesh.from_npz_bytes(store.read_bytes(session.get(m.Shape, shape_id).mesh_blob))
            camera = Camera(pair.azimuth, pair.elevation, pair.camera_distance, pair.fov)
            materials = [
                MaterialSpec(name="fabric", params={"albedo": [0.15, 0.25, 0.65], "roughness": 0.9}),
                MaterialSpec(name="fabric", params={"albedo": [0.15, 0.25, 0.65], "roughness": 0.9}),
                MaterialSpec(name="steel", params={"albedo": [0.75, 0.75, 0.78], "roughness": 0.3, "metallic": 1.0}),
            ]
            beauty = renderer.beauty(mesh, materials, camera, EnvmapSpec(store.resolve(envmap.blob)),
                                     size=EXEMPLAR, spp=4)
            part_map = renderer.part_ids(mesh, camera, size=EXEMPLAR)
            if n == 0:
                part_map[part_map == 3] = 0
                hidden_part = col.parts[shape_id][2]
            session.get(m.Exemplar, pair.exemplar_id).image_blob = store.put_image(beauty.srgb)
            session.add(m.Alignment(pair_id=pair_id, method="flow-crf", crf_blob=store.put_array(part_map)))
    return hidden_part


@pytest.mark.render
def test_substances_stage_end_to_end_and_idempotent(
    db_url: str, store, monkeypatch: pytest.MonkeyPatch  # type: ignore[no-untyped-def]
) -> None:
    with session_scope(db_url) as session:
        col = seed_collection(session, store, exemplar_size=EXEMPLAR)
    hidden_part = _add_alignments(db_url, store, col)

    # a run interrupted (Ctrl-C) after the first epoch leaves a resumable checkpoint behind, its row
    # failed rather than "training" (nobody trains it any more)
    from photoshape_flow.recognition import substances as substance_train  # where train_or_resume finds it

    original = substance_train.train_substance_net

    def interrupted(*args, on_epoch, **kwargs):  # type: ignore[no-untyped-def]
        def save_then_die(checkpoint, metrics):  # type: ignore[no-untyped-def]
            on_epoch(checkpoint, metrics)
            raise KeyboardInterrupt

        return original(*args, on_epoch=save_then_die, **kwargs)

    monkeypatch.setattr(substance_train, "train_substance_net", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_substances(bootstrap_count=6, size=32, spp=2, train_config="tiny")
    monkeypatch.setattr(substance_train, "train_substance_net", original)
    with session_scope(db_url) as session:
        (partial,) = session.execute(sa.select(m.Classifier)).scalars()
    assert partial.epoch == 1 and partial.status == "failed" and partial.checkpoint_blob
    assert partial.error.startswith("KeyboardInterrupt")

    summary = run_substances(bootstrap_count=6, size=32, spp=2, train_config="tiny")
    assert summary["bootstrap"]["rendered"] == 0 and summary["bootstrap"]["skipped"] == 6
    assert summary["network"]["resumed_from_epoch"] == 1
    assert summary["network"]["epochs_run"] == [2]
    assert summary["part_substances"]["updated"] == 3 and summary["part_substances"]["failed"] == 0

    with session_scope(db_url) as session:
        (classifier,) = session.execute(sa.select(m.Classifier)).scalars()
        rows = list(session.execute(sa.select(m.PartSubstance)).scalars())
    assert classifier.kind == "substance" and classifier.status == "ok" and classifier.epoch == 2
    assert store.exists(classifier.checkpoint_blob)
    assert classifier.metrics["split"] == "val" and 0 <= classifier.metrics["pixel_accuracy"] <= 1
    assert set(classifier.metrics["iou"]) == set(SUBSTANCE_LABELS)

    assert len(rows) == 9
    for row in rows:
        assert row.classifier_id == classifier.id
        if row.part_id == hidden_part:
            assert not row.observed and row.substance is None and row.pixel_count == 0
            continue
        assert row.observed and row.substance in SUBSTANCES and row.pixel_count > 0
        assert 0 < row.confidence <= 1
        assert row.probs[row.substance] == pytest.approx(row.confidence)
        assert sum(row.probs[s] for s in SUBSTANCES) == pytest.approx(1.0, abs=1e-6)
        probs = store.load_array(row.probs["map_blob"])
        assert probs.shape == (len(SUBSTANCE_LABELS), EXEMPLAR, EXEMPLAR)
        np.testing.assert_allclose(probs.astype(np.float32).sum(axis=0), 1.0, atol=1e-2)

    counts = {model: _count(db_url, model) for model in (m.Rendering, m.Classifier, m.PartSubstance)}
    again = run_substances(bootstrap_count=6, size=32, spp=2, train_config="tiny")
    assert again["bootstrap"]["rendered"] == 0
    assert again["network"]["epochs_run"] == []
    assert again["part_substances"]["updated"] == 0 and again["part_substances"]["skipped"] == 3
    assert {model: _count(db_url, model) for model in counts} == counts
    with session_scope(db_url) as session:
        after = {r.id: r.updated_at for r in session.execute(sa.select(m.PartSubstance)).scalars()}
        (classifier_after,) = session.execute(sa.select(m.Classifier)).scalars()
    assert after == {r.id: r.updated_at for r in rows}
    assert classifier_after.updated_at == classifier.updated_at

    # the network's BatchNorm prior: chosen on photo-like validation renders once, then read back;
    # parts labelled under another prior are parts labelled anew
    choice = summary["bn_prior"]
    assert again["bn_prior"] == choice and choice["regions"] > 0
    assert set(choice["log_loss"]) == {"None", "16.0", "4.0", "1.0"}
    assert classifier_after.metrics["bn_prior_choice"] == choice
    from photoshape_flow.classify.substance_train import checkpoint_from_bytes, load_model
    from photoshape_flow.recognition.substances import assign_part_substances

    network = load_model(checkpoint_from_bytes(store.read_bytes(classifier.checkpoint_blob)))
    other = 1.0 if choice["bn_prior"] is None else None
    relabelled = assign_part_substances(get_settings(), classifier.id, network, 32, bn_prior=other)
    assert relabelled["updated"] == 3 and relabelled["skipped"] == 0
    with session_scope(db_url) as session:
        moved = {r.id: r.probs for r in session.execute(sa.select(m.PartSubstance)).scalars()}
    assert any(moved[r.id] != r.probs for r in rows if r.observed)
    assert assign_part_substances(get_settings(), classifier.id, network, 32, bn_prior=other)["skipped"] == 3

    # the part-level temperature: fit on held-out renders, cached, refit when they change
    from photoshape_flow.recognition.substance_temperature import substance_temperature

    settings = get_settings()
    first = substance_temperature(settings, classifier.id)
    with session_scope(db_url) as session:
        fitted = session.get(m.Classifier, classifier.id)
        metrics, stamp = dict(fitted.metrics), fitted.updated_at
    assert metrics["part_temperature"] == first  # None here: fewer parts than a fit needs
    assert metrics["part_temperature_parts"] < 20 and metrics["part_temperature_key"]
    assert substance_temperature(settings, classifier.id) == first
    with session_scope(db_url) as session:
        assert session.get(m.Classifier, classifier.id).updated_at == stamp  # cached: nothing written
        held_out = session.execute(sa.select(m.Rendering).where(m.Rendering.kind == "bootstrap",
                                                                m.Rendering.split != "val")).scalars().first()
        held_out.split = "val"
    substance_temperature(settings, classifier.id)
    with session_scope(db_url) as session:
        refit = session.get(m.Classifier, classifier.id).metrics
    assert refit["part_temperature_renders"] == metrics["part_temperature_renders"] + 1
    assert refit["part_temperature_key"] != metrics["part_temperature_key"]

    # a part-balanced loss is another network: trained anew on the bootstrap renders' part maps
    balanced = run_substances(bootstrap_count=6, size=32, spp=2, train_config="tiny",
                              train_overrides={"part_balance": 1.0})
    assert balanced["bootstrap"]["rendered"] == 0 and balanced["network"]["epochs_run"] == [1, 2]
    with session_scope(db_url) as session:
        (retrained,) = session.execute(sa.select(m.Classifier)).scalars()
    assert retrained.config["part_balance"] == 1.0 and retrained.checkpoint_blob != classifier.checkpoint_blob

    # a network that reads photos at a finer pitch than it trains at reads the exemplars at that side
    finer = run_substances(bootstrap_count=6, size=32, spp=2, train_config="tiny", train_overrides={"read_size": 48})
    assert finer["network"]["epochs_run"] == [1, 2]
    assert finer["part_substances"]["updated"] == 3 and finer["part_substances"]["read_size"] == 48
    with session_scope(db_url) as session:
        (network_row,) = session.execute(sa.select(m.Classifier)).scalars()
    assert network_row.config["read_size"] == 48

    # the config's own seed (the profile's `--set substances.network.seed`) is a second training on
    # the same renders, not overridden by the run's seed
    reseeded = run_substances(bootstrap_count=6, size=32, spp=2, train_config=replace(get_config("tiny"), seed=3),
                              train_overrides={"read_size": 48})
    assert reseeded["bootstrap"]["rendered"] == 0 and reseeded["network"]["epochs_run"] == [1, 2]
    with session_scope(db_url) as session:
        (reseeded_row,) = session.execute(sa.select(m.Classifier)).scalars()
    assert reseeded_row.config["seed"] == 3 and reseeded_row.checkpoint_blob != network_row.checkpoint_blob


def test_the_part_recogniser_as_the_substance_network_labels_every_part(db_url: str, store) -> None:
    """`substances.network.arch` on a backbone: a kind-"substance" row, each part classified as a whole."""
    with session_scope(db_url) as session:
        col = seed_collection(session, store, exemplar_size=EXEMPLAR)
    hidden_part = _add_alignments(db_url, store, col)
    summary = run_substances(bootstrap_count=6, size=32, spp=2, train_config=get_config("backbone-tiny"))
    assert summary["part_substances"]["updated"] == 3 and summary["part_substances"]["failed"] == 0
    with session_scope(db_url) as session:
        networks = session.execute(sa.select(m.Classifier)).scalars().all()
        rows = list(session.execute(sa.select(m.PartSubstance)).scalars())
    assert [(n.kind, n.architecture) for n in networks] == [("substance", "efficientnet-lite0-part32")]
    for row in rows:
        if row.part_id == hidden_part:
            assert not row.observed
            continue
        # a painted map: every pixel of a part carries the part's vector, so the vote is unanimous
        assert row.observed and row.substance in SUBSTANCES
        assert row.probs[row.substance] == pytest.approx(row.confidence)
        assert sum(row.probs[s] for s in SUBSTANCES) == pytest.approx(1.0, abs=1e-6)
