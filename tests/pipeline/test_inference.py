"""Inference stage: ranked assignments per part for the baselines and the classifier, idempotent."""

from __future__ import annotations

import numpy as np
import pytest
import sqlalchemy as sa
from tests.pipeline.aligned import BLUE, RED, make_aligned_pairs, solid

from photoshape_flow.classify.assignment import color_match, median_lab, random_of_substance, substance_vector
from photoshape_flow.config import get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.recognition.inference import run_all_methods, run_inference


@pytest.fixture
def aligned_pair(db_url: str, store) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """A pair whose exemplar shows a red seat (part 1) above brown legs (part 2); part 3 is hidden."""
    made = make_aligned_pairs(db_url, store, 1)
    return {**made, "pair": made["pairs"][0]}  # type: ignore[dict-item]


def _top1(method_key: str) -> dict[int, tuple[int | None, bool]]:
    with session_scope() as session:
        rows = session.execute(
            sa.select(m.Assignment.part_id, m.Assignment.material_id, m.Assignment.unobserved)
            .where(m.Assignment.method_key == method_key, m.Assignment.rank == 1)
        ).all()
    return {r.part_id: (r.material_id, r.unobserved) for r in rows}


def test_color_match_picks_the_material_of_the_same_colour(aligned_pair: dict[str, int]) -> None:
    summary = run_inference("color-match")
    assert summary.pairs_done == 1 and not summary.pairs_failed
    top = _top1("color-match")
    assert top[aligned_pair["seat"]] == (aligned_pair["red_leather"], False)
    assert top[aligned_pair["legs"]] == (aligned_pair["walnut"], False)
    hidden_material, unobserved = top[aligned_pair["hidden"]]
    assert unobserved  # the hidden part is marked, and got a material of its prior substance
    with session_scope() as session:
        assert session.get(m.Material, hidden_material).substance in {"fabric", "leather"}


def test_no_classifier_draws_from_the_predicted_substance_reproducibly(aligned_pair: dict[str, int]) -> None:
    run_inference("no-classifier")
    first = _top1("no-classifier")
    with session_scope() as session:
        subs = {pid: session.get(m.Material, mid).substance for pid, (mid, _) in first.items()}
    assert subs[aligned_pair["seat"]] == "leather" and subs[aligned_pair["legs"]] == "wood"
    # a stale hash forces a recompute: the same key gives the same draw
    with session_scope() as session:
        session.execute(sa.update(m.Assignment).values(params_hash="stale"))
    run_inference("no-classifier")
    assert _top1("no-classifier") == first


def test_rerun_adds_no_rows_and_builtin_keeps_part_materials(aligned_pair: dict[str, int]) -> None:
    run_all_methods(["builtin", "color-match"])
    with session_scope() as session:
        count = session.execute(sa.select(sa.func.count()).select_from(m.Assignment)).scalar_one()
    summaries = run_all_methods(["builtin", "color-match"])
    assert all(s.pairs_done == 0 for s in summaries)
    with session_scope() as session:
        assert session.execute(sa.select(sa.func.count()).select_from(m.Assignment)).scalar_one() == count
        builtin = session.execute(sa.select(m.Assignment).where(m.Assignment.method == "builtin")).scalars().all()
    assert len(builtin) == 3 and all(a.material_id is None and a.params["builtin"] for a in builtin)


def test_classifier_is_skipped_without_a_trained_model(aligned_pair: dict[str, int]) -> None:
    assert run_all_methods(["classifier"]) == []
    with pytest.raises(ValueError, match="no trained material classifier"):
        run_inference("classifier", settings=get_settings())


def test_pure_helpers() -> None:
    assert substance_vector(None)[0] == 0 and np.isclose(substance_vector(None).sum(), 1)
    assert np.isclose(substance_vector({"wood": 2.0, "background": 5.0}).sum(), 1)
    mats = [(1, "wood"), (2, "wood"), (3, "metal")]
    assert random_of_substance("wood", mats, seed=3) == random_of_substance("wood", mats, seed=3)
    assert {r.material_id for r in random_of_substance("wood", mats, seed=3)} == {1, 2}
    red = median_lab(solid(RED))
    ranked = color_match(red, {1: median_lab(solid(BLUE)), 2: red}, {1: "wood", 2: "wood"})
    assert ranked[0].material_id == 2 and ranked[0].score == pytest.approx(1.0)


def test_new_part_substances_make_exactly_that_pairs_rows_stale(aligned_pair: dict[str, int]) -> None:
    """A retrained substance network rewrites part substances: the baseline that reads them follows."""
    assert run_inference("no-classifier").pairs_done == 1
    assert run_inference("no-classifier").pairs_done == 0  # nothing changed: nothing redone
    with session_scope() as session:
        row = session.execute(sa.select(m.PartSubstance).where(
            m.PartSubstance.pair_id == aligned_pair["pair"], m.PartSubstance.part_id == aligned_pair["seat"])
        ).scalar_one()
        row.substance, row.probs, row.params_hash = "fabric", {"fabric": 0.9, "leather": 0.1}, "retrained"
    again = run_inference("no-classifier")
    assert again.pairs_done == 1 and not again.pairs_failed
    with session_scope() as session:
        seat = session.get(m.Material, _top1("no-classifier")[aligned_pair["seat"]][0])
    assert seat.substance == "fabric"
    assert run_inference("no-classifier").pairs_done == 0


def test_a_part_too_small_to_classify_keeps_the_substance_the_network_saw(aligned_pair: dict[str, int]) -> None:
    with session_scope() as session:  # the substance stage saw a few pixels of the hidden part
        row = session.execute(sa.select(m.PartSubstance).where(
            m.PartSubstance.pair_id == aligned_pair["pair"], m.PartSubstance.part_id == aligned_pair["hidden"])
        ).scalar_one()
        row.observed, row.substance, row.probs, row.pixel_count = True, "wood", {"wood": 0.8, "fabric": 0.2}, 3
    run_inference("no-classifier")
    material, unobserved = _top1("no-classifier")[aligned_pair["hidden"]]
    assert unobserved  # still too small for the classifier, and marked so
    with session_scope() as session:
        assert session.get(m.Material, material).substance == "wood"  # not the fabric/leather prior


def _untrained_classifier(store, material_ids: list[int], substances: list[str]) -> int:  # type: ignore[no-untyped-def]
    """A material classifier row with random weights: enough to exercise inference's plumbing."""
    import torch

    from photoshape_flow.classify.checkpoint import make_checkpoint, slim, to_bytes
    from photoshape_flow.classify.resnet import MaterialResNet

    torch.manual_seed(0)
    model = MaterialResNet("resnet18", num_materials=len(material_ids), width=8)
    checkpoint = make_checkpoint(model, materials=material_ids, material_substances=substances, image_size=32,
                                 config={}, epoch=1)
    with session_scope() as session:
        row = m.Classifier(name="untrained", kind="material", architecture="resnet18", materials=material_ids,
                           config={"min_region_fraction": 0.005}, status="ok",
                           checkpoint_blob=store.put_bytes(to_bytes(slim(checkpoint)), "pt"))
        session.add(row)
        session.flush()
        return row.id


def _shrink_legs_and_classify(aligned_pair: dict[str, int], store) -> dict[int, m.Assignment]:  # type: ignore[no-untyped-def]
    """Shrink the legs to 4 x 5 pixels (still classified, >= 16 px, but under 0.5% of the 64 x 64
    image), run the classifier method with a random-weight classifier; rank-1 rows by part."""
    with session_scope() as session:
        query = sa.select(m.Alignment).where(m.Alignment.pair_id == aligned_pair["pair"])
        alignment = session.execute(query).scalar_one()
        part_map = store.load_image(alignment.crf_blob).copy()
        part_map[part_map == 2] = 0
        part_map[40:44, 20:25] = 2
        alignment.crf_blob = store.put_image(part_map)
    names = ["red_leather", "blue_leather", "walnut", "grey_fabric"]
    _untrained_classifier(store, [aligned_pair[n] for n in names], ["leather", "leather", "wood", "fabric"])
    assert run_inference("classifier").pairs_done == 1
    with session_scope() as session:
        rows = session.execute(sa.select(m.Assignment).where(m.Assignment.method == "classifier",
                                                             m.Assignment.rank == 1)).scalars().all()
        session.expunge_all()
    return {row.part_id: row for row in rows}


def test_a_part_smaller_than_any_training_region_is_ranked_without_the_head(  # type: ignore[no-untyped-def]
    aligned_pair: dict[str, int], store
) -> None:
    by_part = _shrink_legs_and_classify(aligned_pair, store)
    legs, seat = by_part[aligned_pair["legs"]], by_part[aligned_pair["seat"]]
    assert legs.params.get("classifier_head") is False and not legs.unobserved
    assert "classifier_head" not in seat.params
    # without the (random) head, the substance network (wood 0.8) and the brown colour decide
    assert legs.material_id == aligned_pair["walnut"]
    # every ranked row carries its posterior: per part they sum to 1 (top_k 5 >= the 4 materials)
    with session_scope() as session:
        sums = dict(session.execute(sa.select(m.Assignment.part_id, sa.func.sum(m.Assignment.posterior))
                                    .where(m.Assignment.method == "classifier").group_by(m.Assignment.part_id)).all())
    assert {aligned_pair["legs"], aligned_pair["seat"]} <= sums.keys() and all(
        v == pytest.approx(1.0) for v in sums.values()), sums
    assert legs.posterior is not None and legs.posterior > legs.score  # normalised: above the raw product


def test_a_part_smaller_than_any_training_region_takes_the_substance_networks_substance(  # type: ignore[no-untyped-def]
    aligned_pair: dict[str, int], store
) -> None:
    # the network's pixel votes said fabric although its mean confidence leans to wood (and the legs
    # are brown): at this size only the network's own decision is evidence about the substance
    with session_scope() as session:
        row = session.execute(sa.select(m.PartSubstance).where(
            m.PartSubstance.pair_id == aligned_pair["pair"], m.PartSubstance.part_id == aligned_pair["legs"])
        ).scalar_one()
        row.substance, row.probs = "fabric", {"wood": 0.6, "fabric": 0.4}
    legs = _shrink_legs_and_classify(aligned_pair, store)[aligned_pair["legs"]]
    assert legs.params.get("classifier_head") is False
    assert legs.substance == "fabric" and legs.material_id == aligned_pair["grey_fabric"]


def test_pairs_a_live_worker_holds_are_reported_blocked_not_skipped(aligned_pair: dict[str, int]) -> None:
    from photoshape_flow.db import claims

    with session_scope() as session:
        claims.claim(session, "inference:color-match", [str(aligned_pair["pair"])], worker="other-worker",
                     lease_seconds=900)
    summary = run_inference("color-match")
    assert (summary.pairs_done, summary.pairs_skipped) == (0, 0)
    assert [(h.worker, h.count) for h in summary.blocked] == [("other-worker", 1)]
