"""Training-render stage: resumable, split by shapes and envmaps, label maps stored, saturation recorded."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from tests.synth.collection import seed_collection

from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.recognition.render_pools import derived_val_shapes, load_pools
from photoshape_flow.recognition.training_renders import run_training_renders
from photoshape_flow.synth.spec import RenderSpec, metered_gains


def _label_map(store, ref: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    return store.load_array(ref) if ref.endswith(".npy") else store.load_image(ref)


def _renderings(url: str, kind: str) -> list[m.Rendering]:
    with session_scope(url) as session:
        return list(session.execute(sa.select(m.Rendering).where(m.Rendering.kind == kind)).scalars())


@pytest.mark.render
def test_bootstrap_round_is_resumable_and_split_by_shapes_and_envmaps(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        col = seed_collection(session, store)

    summary = run_training_renders("bootstrap", count=6, size=32, spp=2, batch=4)
    assert summary["splits"] == {"train": 5, "val": 1}
    assert summary["rendered"] == 6 and summary["failed"] == 0 and summary["pose_source"] == "pairs"
    assert summary["split_source"] == "shape.split"
    rows = _renderings(db_url, "bootstrap")
    assert sorted(r.key for r in rows) == [f"bootstrap/train/{i:06d}" for i in range(5)] + ["bootstrap/val/000000"]
    for row in rows:
        # split by shapes and envmaps, never by images
        assert col.shapes[row.shape_id] == row.split and col.envmaps[row.envmap_id] == row.split
        assert col.pairs[row.pair_id] == row.shape_id
        assert row.status == "ok" and row.saturated_fraction is not None and row.seconds > 0
        assert set(row.blobs) >= {"beauty", "hdr", "part_ids", "material_ids", "substance_ids"}
        spec = RenderSpec.from_dict(row.params)
        assert spec.key == row.key and row.params["size"] == 32
        part_ids = _label_map(store, row.blobs["part_ids"])
        material_ids = _label_map(store, row.blobs["material_ids"])
        lut = np.zeros(int(part_ids.max()) + 1, np.int64)
        for index, material_id in spec.material_by_index().items():
            if index < len(lut):
                lut[index] = material_id
        np.testing.assert_array_equal(material_ids, lut[part_ids])
        assert (part_ids > 0).any()

    again = run_training_renders("bootstrap", count=6, size=32, spp=2, batch=4)
    assert again["rendered"] == 0 and again["skipped"] == 6
    assert len(_renderings(db_url, "bootstrap")) == 6

    more = run_training_renders("bootstrap", count=8, size=32, spp=2, batch=4)
    assert more["rendered"] == 2 and more["skipped"] == 6
    assert len(_renderings(db_url, "bootstrap")) == 8


@pytest.mark.render
def test_overexposed_renders_are_recorded_as_rejected(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        seed_collection(session, store, envmap_gain=80.0)
    summary = run_training_renders("bootstrap", count=2, size=32, spp=2)
    assert summary["rejected"] == 2
    rows = _renderings(db_url, "bootstrap")
    assert [r.status for r in rows] == ["rejected", "rejected"]
    assert all(r.saturated_fraction > 0.05 and "saturated" in r.error for r in rows)
    # rejected items are final: a re-run does not render them again
    assert run_training_renders("bootstrap", count=2, size=32, spp=2)["skipped"] == 2


def test_training_round_pools_use_part_substances(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        col = seed_collection(session, store)
        pair_id, shape_id = next(iter(col.pairs.items()))
        seat, back, legs = col.parts[shape_id]
        # the seat as the substance stage stores it (probabilities beside background and the map's blob),
        # the back with its label alone
        seat_probs = {"leather": 0.6, "wood": 0.3, "fabric": 0.0, "background": 0.1, "map_blob": "ab.npy"}
        for part_id, substance, probs in ((seat, "leather", seat_probs), (back, "fabric", {}), (legs, None, {})):
            session.add(m.PartSubstance(pair_id=pair_id, part_id=part_id, observed=substance is not None,
                                        substance=substance, pixel_count=10 if substance else 0, probs=probs))
    with session_scope(db_url) as session:
        pools = load_pools(session, "training")
        bootstrap = load_pools(session, "bootstrap")
    # what the renders draw from: the network's probabilities over substances (a label alone is certain)
    assert pools.part_substances == {pair_id: {seat: {"leather": 0.6, "wood": 0.3}, back: {"fabric": 1.0},
                                               legs: None}}
    assert pools.shape_substances == {shape_id: {seat: ["leather"], back: ["fabric"]}}
    # only pairs with substances are drawn in the training round
    candidates = [c for split in ("train", "val") for c in pools.priors[split].candidates]
    assert [c.pair_id for c in candidates] == [pair_id]
    assert bootstrap.part_substances is None
    assert len([c for s in ("train", "val") for c in bootstrap.priors[s].candidates]) == 3


def test_no_pairs_falls_back_to_shapes_and_derived_split(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        seed_collection(session, store, shape_splits=("train",) * 4, with_pairs=False)
    with session_scope(db_url) as session:
        pools = load_pools(session, "bootstrap")
    assert pools.pose_source == "default" and pools.split_source == "derived"
    val = [c.shape_id for c in pools.priors["val"].candidates]
    train = [c.shape_id for c in pools.priors["train"].candidates]
    assert len(val) == 1 and len(train) == 3 and not set(val) & set(train)
    assert all(c.pair_id is None for c in pools.priors["train"].candidates)
    assert derived_val_shapes({1: "a", 2: "b"}) == derived_val_shapes({2: "b", 1: "a"})
    assert get_settings().seed == 0


@pytest.mark.render
def test_a_failing_item_is_recorded_and_retried(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        col = seed_collection(session, store)
        val_envmap = next(e for e, split in col.envmaps.items() if split == "val")
        ref = session.get(m.Envmap, val_envmap).blob
    store.path(ref).unlink()  # the val envmap's file is gone: val items fail, train items render
    summary = run_training_renders("bootstrap", count=2, size=32, spp=2)
    assert summary["rendered"] == 1 and summary["failed"] == 1
    rows = {r.split: r for r in _renderings(db_url, "bootstrap")}
    assert rows["val"].status == "failed" and "missing" in rows["val"].error and rows["val"].blobs == {}
    assert rows["train"].status == "ok"
    again = run_training_renders("bootstrap", count=2, size=32, spp=2)
    assert again["skipped"] == 1 and again["failed"] == 1


@pytest.mark.render
def test_units_of_a_fan_out_render_what_one_call_renders(db_url: str, store, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The stage's work units (as workers claim them) give the same rows as one whole call."""
    from photoshape_flow.db import migrate
    from photoshape_flow.profiles import resolve_profile
    from photoshape_flow.stages import StageContext, plan_batches, process

    with session_scope(db_url) as session:
        seed_collection(session, store)
    whole = run_training_renders("bootstrap", count=5, size=24, spp=2)
    expected = {r.key: r.params_hash for r in _renderings(db_url, "bootstrap")}
    assert whole["rendered"] == 5

    other = tmp_path / "other.db"
    url = f"sqlite:///{other}"
    migrate.upgrade(url)
    with session_scope(url) as session:
        seed_collection(session, store)
    settings = get_settings().model_copy(update={"database_url": url})
    ctx = StageContext.create(settings)
    profile = resolve_profile("tiny", ["substances.bootstrap_count=5", "substances.size=24", "substances.spp=2"])
    units = plan_batches("substances", profile, ctx, batch_size=2)
    assert [len(u.ids) for u in units] == [2, 2, 1]
    reports = [process("substances", unit, profile, ctx) for unit in reversed(units)]  # any order
    assert sum(r.done for r in reports) == 5
    assert {r.key: r.params_hash for r in _renderings(url, "bootstrap")} == expected
    assert sum(process("substances", u, profile, ctx).done for u in units) == 0  # claimed and done: skipped

    def attempts() -> list[int]:
        with session_scope(url) as session:
            return sorted(session.execute(sa.select(m.WorkClaim.attempts).where(
                m.WorkClaim.stage == "substances:bootstrap")).scalars())

    assert attempts() == [1] * 5
    with session_scope(url) as session:  # a material is added: the pools change, the claims re-open
        session.add(m.Material(name="added", substance="wood", enabled=True, status="ok"))
    for unit in units:
        process("substances", unit, profile, ctx)
    assert attempts() == [2] * 5


def test_metered_gains_bring_every_map_to_the_median_mean() -> None:
    gains = metered_gains({1: 0.2, 2: 1.0, 3: 5.0, 4: 0.0})
    assert gains[2] == 1.0 and gains[1] == pytest.approx(5.0) and gains[3] == pytest.approx(0.2)
    assert gains[4] == 1.0  # no measured mean: as ingested
    assert metered_gains({1: 0.0}) == {1: 1.0}


@pytest.mark.render
def test_metered_exposure_scales_each_map_to_the_median_and_re_renders(db_url: str, store) -> None:  # type: ignore[no-untyped-def]
    with session_scope(db_url) as session:
        col = seed_collection(session, store, envmap_splits=("train", "train", "val"))
        bright = min(col.envmaps)
        for row in session.execute(sa.select(m.Envmap)).scalars():
            row.meta = {"stats": {"mean_luminance": 4.0 if row.id == bright else 1.0}}  # median 1: gains 1/4, 1, 1

    def object_radiance() -> dict[str, tuple[int, float]]:
        out = {}
        for row in _renderings(db_url, "bootstrap"):
            covered = (_label_map(store, row.blobs["part_ids"]) > 0).astype(np.uint8)
            # away from the silhouette, where the pixel filter blends the white background in
            inside = cv2.erode(covered, np.ones((7, 7), np.uint8)) > 0
            assert inside.sum() >= 10
            out[row.key] = (row.envmap_id, float(store.load_image(row.blobs["hdr"])[inside].sum()))
        return out

    assert run_training_renders("bootstrap", count=8, size=64, spp=2)["rendered"] == 8
    before = object_radiance()
    assert bright in {envmap for envmap, _ in before.values()}
    assert run_training_renders("bootstrap", count=8, size=64, spp=2, exposure="metered")["rendered"] == 8
    for key, (envmap_id, radiance) in object_radiance().items():
        expected = 0.25 if envmap_id == bright else 1.0  # the gain is in each item's hash: all re-rendered
        assert radiance / before[key][1] == pytest.approx(expected, rel=0.1)
    with pytest.raises(ValueError, match="exposure"):
        run_training_renders("bootstrap", count=1, size=32, spp=2, exposure="auto")
