"""Fit weights fitted on validation renders: stored on the classifier, used by the stage, in its params hash.

The tiny demo's photos planted as pairs (`test_fit._plant_pairs`), a random-weight classifier
checkpoint on the planted classifier row (the ranker's plumbing, not its accuracy, is under test), and
a few bootstrap-round renders, half of them validation renders, as the calibration's cases.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.store import BlobStore

pytestmark = [pytest.mark.slow, pytest.mark.render]


def _give_checkpoint(store: BlobStore) -> None:
    """A random-weight checkpoint over the planted classifier's materials (so the ranker can run)."""
    import torch

    from photoshape_flow.classify.checkpoint import make_checkpoint, slim, to_bytes
    from photoshape_flow.classify.resnet import MaterialResNet

    with session_scope() as session:
        row = session.execute(sa.select(m.Classifier)).scalar_one()
        subs = [session.get(m.Material, mid).substance for mid in row.materials]
        torch.manual_seed(0)
        model = MaterialResNet("resnet18", num_materials=len(row.materials), width=8)
        checkpoint = make_checkpoint(model, materials=list(row.materials), material_substances=subs, image_size=32,
                                     config={}, epoch=1)
        row.checkpoint_blob = store.put_bytes(to_bytes(slim(checkpoint)), "pt")


def _fit_rows(url: str) -> dict[tuple[int, int], list[m.Assignment]]:
    with session_scope(url) as session:
        rows = session.execute(sa.select(m.Assignment).where(m.Assignment.method == "fit")
                               .order_by(m.Assignment.pair_id, m.Assignment.part_id, m.Assignment.rank)).scalars()
        out: dict[tuple[int, int], list[m.Assignment]] = {}
        for r in rows:
            out.setdefault((r.pair_id, r.part_id), []).append(r)
        return out


def test_fitted_weights_are_stored_used_and_hashed(tiny_demo: Path, db_url: str, store: BlobStore) -> None:
    from tests.pipeline.test_fit import _plant_pairs

    from photoshape_flow.fitting.calibration import MODELS
    from photoshape_flow.networks.calibrations import Calibration
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.recognition.training_renders import run_training_renders
    from photoshape_flow.stages import StageContext
    from photoshape_flow.stages.run import run_stage

    _plant_pairs(tiny_demo, db_url, store)
    _give_checkpoint(store)
    summary = run_training_renders("bootstrap", 6, 48, 4, val_fraction=0.5)
    assert summary["splits"]["val"] >= 2, summary
    ctx = StageContext.create()

    hand = run_stage("fit", resolve_profile("tiny", ["fit.calibration_cases=0"]), ctx)
    assert hand.details[next(iter(hand.details))]["weights"]["source"] == "hand-set"
    hand_rows = _fit_rows(db_url)
    calls: list[tuple[str, int, int]] = []
    ctx = StageContext.create(progress=lambda task, done, total: calls.append((task, done, total)))
    fitted = run_stage("fit", resolve_profile("tiny", ["fit.calibration_cases=3"]), ctx)
    bar = [c for c in calls if c[0] == "fit calibration renders"]
    assert bar[0][1] == 0 and bar[-1][1] == bar[-1][2] >= 2  # announced, then counted to its end
    report = fitted.details[next(iter(fitted.details))]["weights"]
    with session_scope(db_url) as session:
        stored = Calibration.of(session.execute(sa.select(m.Classifier)).scalar_one()).fit
    assert stored is not None
    record = stored["record"]
    assert record is not None and record["renders"] >= 1 and record["cases"] >= 1, stored
    with session_scope(db_url) as session:  # photos degraded at the stored exemplars' median side (D45)
        sizes = session.execute(sa.select(m.Exemplar.size).where(m.Exemplar.size.is_not(None))).scalars().all()
    assert sizes and record["photo_size"] == int(np.median(sizes))
    assert report["source"] == "fitted" and report["temperature"] == pytest.approx(record["temperature"], abs=1e-4)
    assert sum(record["weights"].values()) == pytest.approx(1.0, abs=1e-4)
    tiny = resolve_profile("tiny").profile.fit
    assert record["blur"] == report["blur"] == tiny.blur  # measured at the profile's blur, which the stage uses (D64)
    assert all(w >= 0 for w in record["weights"].values())
    # the kept model (all weights fitted, or the hand-set ones with or without a fitted temperature) has the lowest
    # held-out log-loss (D48); hand-set weights keep their proportions
    assert record["model"] in MODELS and report["model"] == record["model"]
    held = record["held_out"]
    if held.get("cases"):
        assert held[record["model"]]["log_loss"] == min(held[model]["log_loss"] for model in MODELS)
    if record["model"] != "fitted":
        assert record["weights"]["prior"] / record["weights"]["color"] == pytest.approx(
            tiny.prior_weight / tiny.color_weight, rel=1e-3)

    rows = _fit_rows(db_url)
    assert fitted.done == len({pair for pair, _ in rows})  # the weights' hash re-ran every pair
    assert {r[0].params_hash for r in rows.values()}.isdisjoint({r[0].params_hash for r in hand_rows.values()})
    # the stored weights are the ones ranking: scores are softmax(-cost / fitted temperature)
    w, t = record["weights"], record["temperature"]
    observed = [ranked for ranked in rows.values() if ranked[0].params["fit"].get("cost") is not None]
    assert observed
    for ranked in observed:
        fit = [r.params["fit"] for r in ranked]
        for f in fit:
            if f["distance"] is not None:
                assert f["cost"] == pytest.approx(f["distance"] + w["prior"] * -math.log(f["prior"]), abs=1e-4)
        low = min(f["cost"] for f in fit)
        expected = np.exp(-(np.array([f["cost"] for f in fit]) - low) / t)
        assert np.allclose([r.score for r in ranked], expected / expected.sum(), atol=1e-3)
        assert [r.posterior for r in ranked] == [r.score for r in ranked]  # calibrated: the gallery's confidence
    hand_observed = [ranked for ranked in hand_rows.values() if ranked[0].params["fit"].get("cost") is not None]
    assert hand_observed and all(r.posterior is None for ranked in hand_observed for r in ranked)  # uncalibrated

    again = run_stage("fit", resolve_profile("tiny", ["fit.calibration_cases=3"]), ctx)
    assert again.done == 0  # the stored calibration is reused (same key), nothing re-fits or re-ranks


def test_colour_evidence_is_fitted_on_the_renders_and_keys_what_ranks_with_it(
        tiny_demo: Path, db_url: str, store: BlobStore, caplog: pytest.LogCaptureFixture) -> None:
    """D63: each material's colour from the training split's renders, sigma from validation renders seen as photos;
    stored on the classifier, read back by the ranking and named in the keys of what ranks with it."""
    from tests.pipeline.test_fit import _plant_pairs

    from photoshape_flow.config import get_settings
    from photoshape_flow.networks.calibrations import Calibration, material_labs, stored_color_prior
    from photoshape_flow.networks.validation_photos import exemplar_size
    from photoshape_flow.recognition.calibration import fit_color_evidence, photo_color_distances
    from photoshape_flow.recognition.training_renders import run_training_renders

    _plant_pairs(tiny_demo, db_url, store)
    run_training_renders("training", 16, 48, 4, val_fraction=0.5)
    settings = get_settings()
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Classifier)).scalar_one()
        assert not Calibration.of(row).colour_key  # nothing fitted yet: older keys stay as they were
        previews = material_labs(session, store, row.materials)
        with caplog.at_level(logging.INFO, logger="photoshape_flow.recognition.calibration"):
            labs, sigma = fit_color_evidence(session, store, settings, previews, row)
        distances = photo_color_distances(session, store, settings.seed, labs, exemplar_size(session))
    assert len(distances) > 0 and sigma is not None and sigma >= 1.0
    # the log names what sigma was fit on (these renders keep their HDR: photos, not the stored images)
    assert f"fit on {len(distances)} part distances in validation renders seen as photos" in caplog.text
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Classifier)).scalar_one()
        record = Calibration.of(row)
        assert record.color_sigma == pytest.approx(sigma) and record.colour_key == {"colour": record.color_sigma_key}
        rendered = {int(k) for k in record.color_labs}
        assert rendered and rendered <= set(previews)  # colours of materials the renders show often enough
        for mid in rendered:
            assert labs[mid] == pytest.approx(record.color_labs[str(mid)], abs=1e-3)
            assert not np.allclose(labs[mid], previews[mid], atol=0.5)  # a preview is not how the renders show it
        matrix, read_sigma = stored_color_prior(session, store, row.materials, row)
        assert read_sigma == pytest.approx(sigma)
        for i, mid in enumerate(row.materials):
            if mid in labs:
                assert matrix[i] == pytest.approx(labs[mid], abs=1e-3)
        again = fit_color_evidence(session, store, settings, previews, row)  # cached: read back, same
    assert again[1] == pytest.approx(sigma) and all(again[0][k] == pytest.approx(v, abs=1e-3) for k, v in labs.items())
