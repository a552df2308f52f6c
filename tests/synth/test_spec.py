"""Training-render specs: real jitter over the paper's ranges, key-seeded reproducibility, priors."""

from __future__ import annotations

import json
import math
from collections import Counter

import numpy as np
import pytest

from photoshape_flow.hashing import item_seed
from photoshape_flow.synth import priors
from photoshape_flow.synth.spec import (
    AZIMUTH_JITTER,
    ELEVATION_JITTER,
    PairCandidate,
    PairPosePrior,
    PartInfo,
    RenderSpec,
    item_key,
    sample_render_spec,
    spec_for_key,
)

PARTS = {7: [PartInfo(71, 1, "seat_cushion"), PartInfo(72, 2, "back"), PartInfo(73, 3, "legs")]}
MATERIALS = {"leather": [1, 2], "fabric": [3], "wood": [4, 5], "metal": [6], "plastic": [8]}
PRIOR = PairPosePrior(candidates=(PairCandidate(7, 70),), poses=((0.3, 0.1),))


def _spec(key: str, seed: int = 0, **kwargs) -> RenderSpec:  # type: ignore[no-untyped-def]
    args = {"pair_pose_prior": PRIOR, "parts": PARTS, "materials_by_substance": MATERIALS, "envmaps": [11, 12]}
    args.update(kwargs)
    return spec_for_key(key, seed, **args)


def test_camera_jitter_covers_the_paper_ranges() -> None:
    specs = [_spec(item_key("training", "train", i)) for i in range(400)]
    d_az = np.array([s.camera.azimuth - 0.3 for s in specs])
    d_el = np.array([s.camera.elevation - 0.1 for s in specs])
    fov = np.array([s.camera.fov for s in specs])
    dist = np.array([s.camera.distance for s in specs])
    env = np.array([s.envmap.scale for s in specs])
    for values, lo, hi in (
        (d_az, -AZIMUTH_JITTER, AZIMUTH_JITTER),
        (d_el, -ELEVATION_JITTER, ELEVATION_JITTER),
        (fov, 50.0, 60.0),
        (dist, 1.3, 1.75),
        (env, 0.9, 1.2),
    ):
        assert values.min() >= lo and values.max() <= hi
        span = hi - lo
        # not a constant (the original's bug) and spread over the whole range
        assert values.std() > 0.2 * span
        assert values.min() < lo + 0.1 * span and values.max() > hi - 0.1 * span
    assert math.isclose(AZIMUTH_JITTER, math.pi / 12) and math.isclose(ELEVATION_JITTER, math.pi / 24)
    uv = [p.uv for s in specs for p in s.parts]
    scales = np.log2([u.scale for u in uv])
    assert scales.min() >= -1 and scales.max() <= 0.5 and scales.std() > 0.2
    assert all(0 <= u.rotation <= 2 * math.pi and 0 <= u.offset[0] <= 1 and 0 <= u.offset[1] <= 1 for u in uv)
    assert {s.envmap.envmap_id for s in specs} == {11, 12}


def test_same_key_same_spec_and_json_round_trip() -> None:
    key = item_key("bootstrap", "val", 3)
    a, b = _spec(key), _spec(key)
    assert a.to_dict() == b.to_dict()
    assert a.key == key and a.seed == item_seed(0, key, sep=":", bits=63)
    assert _spec(item_key("bootstrap", "val", 4)).to_dict() != a.to_dict()
    assert _spec(key, seed=1).to_dict() != a.to_dict()
    restored = RenderSpec.from_dict(json.loads(a.to_json()))
    assert restored == a
    assert restored.to_dict() == a.to_dict()


def test_observed_substances_condition_materials_and_unobserved_use_the_prior() -> None:
    observed = {70: {71: "leather", 72: "fabric", 73: None}}
    across = {7: {73: ["metal", "metal"]}}
    for i in range(50):
        rng = np.random.default_rng(i)
        spec = sample_render_spec(rng, PRIOR, PARTS, MATERIALS, [11], observed, shape_substances=across)
        by_part = {p.part_id: p for p in spec.parts}
        assert by_part[71].substance == "leather" and by_part[71].material_id in MATERIALS["leather"]
        assert by_part[71].substance_source == "observed"
        assert by_part[72].material_id == 3
        # unobserved part: the substances the part had in the shape's other pairs
        assert by_part[73].substance_source == "prior" and by_part[73].material_id == 6


def test_observed_parts_draw_from_the_networks_probabilities_not_its_most_likely_label() -> None:
    observed = {70: {71: {"leather": 0.25, "wood": 0.75}, 72: {"fabric": 0.5, "plastic": 0.5}, 73: None}}
    counts: dict[int, Counter[str]] = {71: Counter(), 72: Counter()}
    for i in range(400):
        spec = sample_render_spec(np.random.default_rng(i), PRIOR, PARTS, MATERIALS, [11], observed)
        for p in spec.parts:
            if p.part_id in counts:
                assert p.substance_source == "observed" and p.material_id in MATERIALS[p.substance]
                counts[p.part_id][p.substance] += 1
    assert set(counts[71]) == {"leather", "wood"} and 0.17 < counts[71]["leather"] / 400 < 0.33
    assert set(counts[72]) == {"fabric", "plastic"} and 0.4 < counts[72]["fabric"] / 400 < 0.6
    # a substance without an enabled material: its mass goes to what can be drawn
    no_plastic = {**MATERIALS, "plastic": []}
    drawn = {p.substance for i in range(50) for p in sample_render_spec(
        np.random.default_rng(i), PRIOR, PARTS, no_plastic, [11], observed).parts if p.part_id == 72}
    assert drawn == {"fabric"}


def test_bootstrap_draws_from_the_name_prior_and_only_available_substances() -> None:
    materials = {"leather": [1], "fabric": [3], "wood": [4], "metal": [6], "plastic": []}
    counts: Counter[str] = Counter()
    for i in range(600):
        spec = sample_render_spec(np.random.default_rng(i), PRIOR, PARTS, materials, [11], None)
        for p in spec.parts:
            assert p.substance_source == "bootstrap"
            assert p.substance != "plastic"
            if p.name == "legs":
                counts[p.substance] += 1
    # legs: wood/metal favoured by the name prior, yet leather still appears (mixed with uniform)
    assert counts["wood"] + counts["metal"] > 2 * (counts["leather"] + counts["fabric"])
    assert counts["leather"] > 0


def test_priors() -> None:
    assert priors.name_prior("Cushion_left")["fabric"] > priors.name_prior("Cushion_left")["metal"]
    assert priors.name_prior("flltgrey") == priors.uniform_prior()
    assert sum(priors.name_prior("leg").values()) == pytest.approx(1.0)
    assert priors.restrict({"plastic": 1.0}, ["wood", "metal"]) == {"wood": 0.5, "metal": 0.5}
    assert priors.empirical_prior(["wood", "wood", "metal"])["wood"] == pytest.approx(2 / 3)
    with pytest.raises(ValueError):
        priors.restrict({"wood": 1.0}, [])


def test_default_pose_prior_and_errors() -> None:
    prior = PairPosePrior.default_poses([PairCandidate(7, None)])
    az = np.array([p[0] for p in prior.poses])
    el = np.array([p[1] for p in prior.poses])
    assert prior.source == "default" and az.min() < -1 and az.max() > 1 and el.min() >= 0
    spec = sample_render_spec(np.random.default_rng(0), prior, PARTS, MATERIALS, [11])
    assert spec.pair_id is None and spec.pose_source == "default"
    with pytest.raises(ValueError):
        sample_render_spec(np.random.default_rng(0), PRIOR, PARTS, MATERIALS, [])


def test_growing_the_collection_changes_few_items() -> None:
    """Rendezvous choices: a new material or pair only changes the items it wins."""
    keys = [item_key("training", "train", i) for i in range(300)]
    before = [_spec(k) for k in keys]
    more_wood = {**MATERIALS, "wood": [4, 5, 99]}
    after = [_spec(k, materials_by_substance=more_wood) for k in keys]
    changed = [a for a, b in zip(after, before, strict=True) if a.to_dict() != b.to_dict()]
    assert 0 < len(changed) < 0.35 * len(keys)
    for a, b in zip(after, before, strict=True):
        for pa, pb in zip(a.parts, b.parts, strict=True):
            assert pa.uv == pb.uv and pa.substance == pb.substance
            assert pa.material_id == pb.material_id or pa.material_id == 99
        assert a.camera == b.camera and a.envmap == b.envmap

    two_pairs = PairPosePrior(candidates=(PairCandidate(7, 70), PairCandidate(7, 80)), poses=((0.3, 0.1), (0.0, 0.2)),
                              pose_ids=(70, 80))
    grown = [_spec(k, pair_pose_prior=two_pairs) for k in keys]
    new_pair = sum(s.pair_id == 80 for s in grown)
    assert 0.3 * len(keys) < new_pair < 0.7 * len(keys)  # still uniform over the two pairs
    same = [(g, b) for g, b in zip(grown, before, strict=True) if g.pair_id == 70 and g.pose == b.pose]
    assert same and all(g.to_dict() == b.to_dict() for g, b in same)


def test_exposure_range_widens_the_envmap_scale_and_changes_nothing_else() -> None:
    keys = [item_key("training", "train", i) for i in range(200)]
    wide = [_spec(k, env_scale_range=(0.5, 2.0)) for k in keys]
    default = [_spec(k) for k in keys]
    scales = np.array([s.envmap.scale for s in wide])
    assert scales.min() >= 0.5 and scales.max() <= 2.0 and scales.min() < 0.6 and scales.max() > 1.9
    for a, b in zip(wide, default, strict=True):
        da, db = a.to_dict(), b.to_dict()
        da["envmap"].pop("scale"), db["envmap"].pop("scale")
        assert da == db  # one draw whatever the range: camera, envmap, materials and UVs are the same
