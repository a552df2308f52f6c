"""Training examples: label maps derived from the part map through the assignment, saturation filter."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from photoshape_flow.synth.example import label_maps, render_training_example, saturated_fraction
from photoshape_flow.synth.spec import PairCandidate, PairPosePrior, PartInfo, spec_for_key
from photoshape_flow.synth.toy import studio_envmap, toy_chair
from photoshape_flow.vocab import SUBSTANCE_LABELS

MATERIALS = {"leather": [301], "fabric": [302, 303], "wood": [304], "metal": [305], "plastic": [306]}
ALBEDO = {301: (0.3, 0.1, 0.05), 302: (0.2, 0.3, 0.7), 303: (0.6, 0.6, 0.5), 304: (0.5, 0.3, 0.1),
          305: (0.8, 0.8, 0.8), 306: (0.9, 0.9, 0.1)}


def _spec(index: int = 0):  # type: ignore[no-untyped-def]
    shape = toy_chair()
    parts = {1: [PartInfo(10 + p.index, p.index, p.name) for p in shape.parts]}
    prior = PairPosePrior(candidates=(PairCandidate(1, 5),), poses=((0.5, 0.2),))
    spec = spec_for_key(
        f"bootstrap/train/{index:06d}", 0, pair_pose_prior=prior, parts=parts,
        materials_by_substance=MATERIALS, envmaps=[1],
    )
    return shape, spec


def test_label_maps_follow_the_assignment() -> None:
    _, spec = _spec()
    rng = np.random.default_rng(0)
    part_ids = rng.integers(0, 4, (20, 20)).astype(np.uint16)
    material_ids, substance_ids = label_maps(part_ids, spec)
    assert material_ids.dtype == np.uint16 and substance_ids.dtype == np.uint8
    for p in spec.parts:
        where = part_ids == p.index
        assert (material_ids[where] == p.material_id).all()
        assert (substance_ids[where] == SUBSTANCE_LABELS.index(p.substance)).all()
    assert (material_ids[part_ids == 0] == 0).all() and (substance_ids[part_ids == 0] == 0).all()

    part_ids[0, 0] = 9  # a rendered part with no assignment must not get a silent label
    with pytest.raises(ValueError, match="no material"):
        label_maps(part_ids, spec)


def test_saturated_fraction_counts_foreground_only() -> None:
    srgb = np.full((4, 4, 3), 100, np.uint8)
    fg = np.zeros((4, 4), bool)
    fg[:2] = True  # 8 foreground pixels
    srgb[0, :2] = (255, 10, 10)  # 2 saturated foreground pixels
    srgb[3, :] = 255  # saturated background: ignored
    assert saturated_fraction(srgb, fg) == pytest.approx(0.25)
    assert saturated_fraction(srgb, np.zeros((4, 4), bool)) == 0.0


@pytest.mark.render
def test_render_training_example_labels_agree_and_saturation_rejects(tmp_path: Path) -> None:
    from photoshape_flow.render import EnvmapSpec, MaterialSpec
    from photoshape_flow.render.renderer import Renderer
    from photoshape_flow.store import BlobStore

    store = BlobStore(tmp_path / "blobs")
    env_path = store.path(store.put_image(studio_envmap(64, 32), "exr"))
    shape, spec = _spec(1)
    specs = {
        mid: MaterialSpec(name=f"m{mid}", params={"albedo": list(c), "roughness": 0.6, "metallic": 0.0})
        for mid, c in ALBEDO.items()
    }
    renderer = Renderer()
    example = render_training_example(renderer, shape, spec, specs, EnvmapSpec(env_path), size=40, spp=2)
    assert example.srgb.shape == (40, 40, 3) and example.srgb.dtype == np.uint8
    assert example.hdr.dtype == np.float32 and example.part_ids.dtype == np.uint16
    assert example.foreground_fraction > 0.05
    assert not example.rejected
    lut = spec.material_by_index()
    fg = example.part_ids > 0
    expected = np.array([lut.get(int(i), 0) for i in example.part_ids.ravel()]).reshape(40, 40)
    np.testing.assert_array_equal(example.material_ids, expected)
    np.testing.assert_array_equal(example.substance_ids > 0, fg)
    # background is white, the object is not
    assert example.srgb[~fg].mean() > 250 and example.srgb[fg].mean() < 230

    bright = render_training_example(
        renderer, shape, spec, specs, EnvmapSpec(env_path, scale=60.0), size=40, spp=2
    )
    assert bright.saturated_fraction > 0.05 and bright.rejected
