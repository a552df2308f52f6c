"""generate_demo end to end: layout, ground truth, masks that match re-renders, idempotence."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from photoshape_flow.demo import SizePreset, generate_demo, load_groundtruth
from photoshape_flow.demo.envmaps import studio_specs
from photoshape_flow.demo.exemplars import (
    ELEVATION_RANGE,
    FOV_RANGE,
    degrade,
    plan_exemplars,
    sample_camera,
    sample_degradation,
)
from photoshape_flow.demo.material_catalogue import select_recipes
from photoshape_flow.demo.seeding import child_rng
from photoshape_flow.demo.shapes import collection_shapes, heldout_shapes
from photoshape_flow.demo.sizes import SIZES
from photoshape_flow.evaluation.groundtruth import read_groundtruth_file
from photoshape_flow.render.camera import Camera
from photoshape_flow.vocab import SUBSTANCES

TEST_PRESET = SizePreset(
    shapes=3,
    heldout_shapes=1,
    per_substance=1,
    envmaps=1,
    heldout_envmaps=1,
    exemplars=4,
    exemplar_size=96,
    spp=4,
    texture_resolution=64,
    envmap_width=64,
)


# -- planning (no rendering) ----------------------------------------------------------------------


def test_plans_mix_collection_and_heldout_with_unique_assignments() -> None:
    preset = SIZES["small"]
    coll = collection_shapes(0, preset.shapes)
    held = heldout_shapes(0, preset.heldout_shapes, coll)
    recipes = select_recipes(preset.per_substance)
    plans = plan_exemplars(0, preset, coll, held, recipes, studio_specs(0, 2, "heldout"))
    assert len(plans) == preset.exemplars
    inside = [p for p in plans if p.in_collection]
    outside = [p for p in plans if not p.in_collection]
    assert inside and outside
    assert {p.shape_id for p in inside} <= {f.source_id for f in coll}
    assert {p.similar_to for p in outside} <= {f.source_id for f in coll}
    keys = [(p.shape_id, tuple(sorted(p.materials.items()))) for p in plans]
    assert len(set(keys)) == len(keys)
    by_name = {r.name: r.substance for r in recipes}
    for p in plans:
        assert {by_name[m] for m in p.materials.values()} <= set(SUBSTANCES)
        assert all(by_name[m] == p.substances[n] for n, m in p.materials.items())
        assert ELEVATION_RANGE[0] <= p.camera["elevation"] <= ELEVATION_RANGE[1]
        assert FOV_RANGE[0] <= p.camera["fov"] <= FOV_RANGE[1]
    again = plan_exemplars(0, preset, coll, held, recipes, studio_specs(0, 2, "heldout"))
    assert again == plans


def test_camera_frames_the_object() -> None:
    shape = collection_shapes(0, 2)[1].to_shape_mesh()
    vertices = np.concatenate([p.vertices for p in shape.parts])
    for k in range(5):
        cam = sample_camera(child_rng(0, "cam", k), vertices)
        xy, depth = Camera.from_dict(cam).project(vertices, 200)
        assert (depth > 0).all()
        extent = np.abs(xy - 100).max() / 100
        assert 0.79 < extent < 0.95  # fills the frame without being cut off


def test_degradation_keeps_white_background_and_object() -> None:
    rng = np.random.default_rng(0)
    premult = np.zeros((32, 32, 3), np.float32)
    alpha = np.zeros((32, 32), np.float32)
    premult[8:24, 8:24] = 0.05
    alpha[8:24, 8:24] = 1.0
    out = degrade(premult, alpha, sample_degradation(rng))
    assert out.dtype == np.uint8 and out[0, 0].mean() > 240 and out[16, 16].mean() < 100


# -- generation (renders) -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory):
    from photoshape_flow.render.renderer import Renderer

    renderer = Renderer()
    root = tmp_path_factory.mktemp("demo") / "tiny"
    manifest = generate_demo(root, "tiny", seed=0, renderer=renderer, preset=TEST_PRESET)
    return manifest, renderer


@pytest.mark.render
def test_layout_and_groundtruth(demo) -> None:
    manifest, _ = demo
    root = manifest.root
    gt = load_groundtruth(manifest.groundtruth)
    assert len(manifest.shapes) == 3 and len(manifest.materials) == len(SUBSTANCES) and len(manifest.envmaps) == 1
    assert sorted(p.name for p in (root / "exemplars").iterdir()) == [f"ex_{k:04d}.jpg" for k in range(4)]
    assert {p.stem for p in (root / "shapes").glob("*.obj")} == {s for s, t in gt.shapes.items() if t.in_collection}
    held_shape_ids = {s for s, t in gt.shapes.items() if not t.in_collection}
    assert held_shape_ids and all(gt.shapes[s].path.is_file() for s in held_shape_ids)
    assert not set(gt.heldout_envmaps) & {p.stem for p in (root / "envmaps").iterdir()}
    for m in gt.materials.values():
        assert (m.path / "material.json").is_file() and m.substance in SUBSTANCES
    assert {e.in_collection for e in gt.exemplars.values()} == {True, False}
    for stem, ex in gt.exemplars.items():
        shape = gt.shapes[ex.shape]
        assert ex.in_collection == shape.in_collection
        assert list(ex.part_names.values()) == [p.name for p in shape.parts]
        assert set(ex.parts) == set(ex.part_names.values())
        for part in ex.parts.values():
            assert gt.materials[part.material].substance == part.substance
        mask = ex.load_mask()
        image = cv2.imread(str(ex.image))
        assert mask.shape == image.shape[:2] == (ex.size, ex.size)
        ids = set(np.unique(mask).tolist()) - {0}
        assert ids and ids <= set(ex.part_names)
        assert sorted(ex.visible_parts) == sorted(ex.part_names[i] for i in ids)
        # a product photo: near-white background, the object clearly darker on average
        assert image[mask == 0].mean() > 200 and image[mask > 0].mean() < image[mask == 0].mean() - 20, stem
        # the light it was rendered under, in the format's `lighting` (a held-out envmap's file)
        (entry,) = [e for e in read_groundtruth_file(manifest.groundtruth).entries if e.stem == stem]
        assert entry.lighting is not None and entry.lighting.path is not None and entry.lighting.path.is_file()
        assert entry.lighting.path.stem in gt.heldout_envmaps
        assert (entry.lighting.rotation, entry.lighting.scale) == (ex.envmap["rotation"], ex.envmap["scale"])
        labels = ex.substance_mask(SUBSTANCES)
        assert set(np.unique(labels[mask > 0]).tolist()) <= set(range(1, len(SUBSTANCES) + 1))


@pytest.mark.render
def test_masks_match_rerenders_from_the_manifest(demo) -> None:
    """Re-render each exemplar's part map from the recorded camera, through the normal ingest
    reader (OBJ -> parts numbered by first `usemtl`), and compare with the stored mask."""
    from photoshape_flow.geometry.obj import parse_obj
    from photoshape_flow.geometry.preprocess import preprocess

    manifest, renderer = demo
    gt = load_groundtruth(manifest.root)
    for ex in gt.exemplars.values():
        shape = preprocess(parse_obj(gt.shapes[ex.shape].path))
        assert [p.name for p in shape.parts] == [ex.part_names[i] for i in sorted(ex.part_names)]
        ids = renderer.part_ids(shape, ex.camera.to_camera(), size=ex.size)
        mask = ex.load_mask()
        assert (ids == mask).mean() > 0.995, ex.stem
        assert ((ids > 0) == (mask > 0)).mean() > 0.995


@pytest.mark.render
def test_rerun_is_idempotent_and_output_deterministic(demo, tmp_path: Path) -> None:
    manifest, renderer = demo
    root = manifest.root
    files = sorted(p for p in root.rglob("*") if p.is_file())
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in files}
    again = generate_demo(root, "tiny", seed=0, renderer=renderer, preset=TEST_PRESET)
    assert again.rendered == 0
    assert before == {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in files}
    # a fresh folder gets the same bytes (renders: same pixels up to JPEG of identical input)
    other = generate_demo(tmp_path / "tiny", "tiny", seed=0, renderer=renderer, preset=TEST_PRESET)
    assert other.rendered == TEST_PRESET.exemplars
    for path in files:
        twin = other.root / path.relative_to(root)
        if path.suffix == ".jpg":
            a = cv2.imread(str(path)).astype(np.int16)
            b = cv2.imread(str(twin)).astype(np.int16)
            assert np.abs(a - b).mean() < 0.5, path.name
        else:
            assert twin.read_bytes() == path.read_bytes(), path.name


def test_unknown_size_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown demo size"):
        generate_demo(tmp_path, "huge", 0)  # type: ignore[arg-type]


def test_preset_counts_are_sane() -> None:
    for name, preset in SIZES.items():
        assert preset.texture_resolution >= 512, name
        assert preset.exemplar_size <= 512 and preset.exemplars >= 5
    assert SIZES["tiny"].shapes < SIZES["small"].shapes < SIZES["medium"].shapes
