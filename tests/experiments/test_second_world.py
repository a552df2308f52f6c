"""The second evaluation world's pure parts (no Blender): planning, shares, truth entries, catalogs.

The world itself is built outside the test suite (`make second-world`); these tests pin what the
build relies on: the plan is a function of the seed, the held-out shares hold, every ground-truth
entry names every part with a mask value, the subset catalogs ingest under the original keys, and
the build refuses to start without Blender. The Blender round trip runs only where Blender is.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from experiments.second_world import build, plan, scenes, shapes
from experiments.second_world.materials import MaterialAsset

from photoshape_flow.geometry.sources import ShapeItem, discover_shapes
from photoshape_flow.vocab import SUBSTANCES

PART_NAMES = (("seat", "legs"), ("RED_OAK", "chrome", "cushion"), ("Material", "Material.001"), ("leather", "wood"))


def _shapes(n: int) -> list[plan.ShapeInfo]:
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        points = rng.uniform(-0.5, 0.5, (200, 3)) * np.array([0.6, 1.0, 0.7])
        out.append(plan.ShapeInfo("sweethome3d", f"Cat/Cat#piece{i:02d}", f"k{i}", PART_NAMES[i % 4], "chair",
                                  points, from_catalog=i < n - 2))
    return out


LIBRARY = [plan.LibraryMaterial(f"{s}_{k}", s, 0.3) for s in SUBSTANCES for k in range(3)]


def _plans(seed: int, count: int = 56) -> list[plan.ExemplarPlan]:
    split = plan.split_shapes(seed, _shapes(40))
    return plan.plan_world(seed, split, LIBRARY, ["a.hdr", "b.hdr"], count)


def test_plan_is_a_function_of_the_seed_and_stable_when_extended():
    first, again, other = _plans(3), _plans(3), _plans(4)
    assert [p.to_json() for p in first] == [p.to_json() for p in again]
    assert [p.to_json() for p in first] != [p.to_json() for p in other]
    shorter = _plans(3, 30)
    assert [p.to_json() for p in shorter[:24]] == [p.to_json() for p in first[:24]]


@pytest.mark.parametrize("seed", [0, 1, 2, 7])
def test_shares_and_substances_hold(seed):
    plans = _plans(seed)
    assert plan.check_world(plans) == []
    counts = plan.world_counts(plans)
    assert counts["heldout_shape_share"] >= 1 / 3 and counts["open_library_share"] >= 1 / 4
    assert all(counts["substance_parts"][s] > 0 for s in SUBSTANCES)
    split = plan.split_shapes(seed, _shapes(40))
    held = {s.source_id for s in split.heldout}
    assert all((p.shape.source_id in held) == (not p.in_collection) for p in plans)
    assert not any(s.from_catalog is False for s in split.heldout)  # shared models are always ingested
    for p in plans:  # the open-library share shows only variants, the rest only library materials
        assert all((part.variant is not None) == p.open_library for part in p.parts.values())


def test_check_world_names_what_is_missing():
    plans = [p for p in _plans(0) if p.in_collection and not p.open_library]
    problems = plan.check_world(plans)
    assert any("non-ingested shapes" in m for m in problems)
    assert any("non-ingested materials" in m for m in problems)


def _asset(name: str, substance: str, tmp: Path) -> MaterialAsset:
    return MaterialAsset(name, substance, 0.5, tmp / f"{name}.png", 0.4, 0.0, None, "demo", "CC0-1.0", "test")


def test_scene_and_truth_entries_are_complete(tmp_path):
    plans = _plans(0, 16)
    assets = {}
    for p in plans:
        for part in p.parts.values():
            assets[part.material] = _asset(part.material, part.substance, tmp_path)
            assets[part.shown] = _asset(part.shown, part.substance, tmp_path)
    labs = {name: [50.0, 0.0, 0.0] for name in assets}
    for p in plans:
        records = [{"name": n, "object": shapes.part_object(i), "uv_density": 4.0}
                   for i, n in enumerate(p.shape.parts, start=1)]
        desc = scenes.scene_description(p, records, assets, tmp_path / "m.obj", tmp_path / "a.hdr", 1.2,
                                        {"beauty": tmp_path / "b.png", "mask": tmp_path / "m.png"}, 64, 4)
        assert [s["index"] for s in desc["parts"]] == list(range(1, len(records) + 1))
        assert desc["parts"][0]["uv_scale"] == pytest.approx(1 / 2 / 0.5)  # 1/sqrt(D)/scale
        assert desc["hdri"]["strength"] == pytest.approx(p.envmap["strength"] * 0.6 / 1.2, rel=1e-3)
        entry = scenes.groundtruth_entry(p, records, assets, labs, desc, "a.hdr", f"masks/{p.stem}.png")
        assert set(entry["parts"]) == set(p.shape.parts) == set(entry["mask"]["values"].values())
        assert entry["in_collection"] == p.in_collection and entry["open_library"] == p.open_library
        assert set(entry["camera"]) == {"azimuth", "elevation", "distance", "fov"}
        assert entry["lighting"]["rotation"] == pytest.approx((math.pi / 2 - p.envmap["rotation"]) % (2 * math.pi),
                                                              abs=1e-5)
        for name, part in entry["parts"].items():
            assert part["material"] in {m.name for m in LIBRARY} and part["substance"] in SUBSTANCES
            assert ("variant" in part) == p.open_library and part["shown_material"] == p.parts[name].shown
    try:  # the evaluation's own parser, where it exists on this branch
        from photoshape_flow.evaluation.groundtruth import parse_groundtruth_data
    except ImportError:
        return
    parsed = parse_groundtruth_data({"format": "photoshape-groundtruth", "version": 2, "exemplars": [entry]},
                                    tmp_path)
    assert parsed.problems == () and len(parsed.entries) == 1


def test_photo_is_white_where_the_render_is_transparent():
    rgba = np.zeros((64, 64, 4), np.uint16)
    rgba[24:40, 24:40] = (10000, 20000, 30000, 65535)
    photo = cv2.imdecode(np.frombuffer(scenes.finish_photo(rgba, 90), np.uint8), cv2.IMREAD_COLOR)
    assert photo[:8, :8].min() >= 250 and photo[30:34, 30:34].max() < 150


def _catalog(path: Path) -> None:
    props = ("id=test\nname=Test catalog\n"
             "id#1=keep\nname#1=Ch\\u00e4ir one\ncategory#1=Chairs\nmodel#1=/a/one.obj\n"
             "id#2=drop\nname#2=Chair two\ncategory#2=Chairs\nmodel#2=/b/two.obj\n")
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("PluginFurnitureCatalog.properties", props)
        z.writestr("a/one.obj", obj)
        z.writestr("b/two.obj", obj)


def test_subset_catalog_ingests_under_the_original_keys(tmp_path):
    _catalog(tmp_path / "Test.sh3f")
    assert shapes.write_subset_catalog(tmp_path / "Test.sh3f", tmp_path / "out" / "Test.sh3f", {"keep"}) == 1
    items = [i for i in discover_shapes([tmp_path / "out"]) if isinstance(i, ShapeItem)]
    assert [(i.source, i.source_id, i.name) for i in items] == [("sweethome3d", "Test/keep", "Chäir one")]
    assert shapes.collection_keys(tmp_path / "out") == {("sweethome3d", "Test/keep")}
    with zipfile.ZipFile(tmp_path / "out" / "Test.sh3f") as z:
        assert "b/two.obj" not in z.namelist()


def test_build_without_blender_says_how_to_install_it(tmp_path, capsys):
    assert build.main(["--out", str(tmp_path / "w"), "--blender", str(tmp_path / "no-blender")]) == 2
    assert "apt-get install -y blender" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


@pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed (apt-get install -y blender)")
def test_blender_renders_a_scene_and_its_exact_part_mask(tmp_path):
    """Two quads side by side: the mask holds both part indices, the beauty pass is opaque there."""
    mesh = tmp_path / "m.obj"
    mesh.write_text("o part_01\nv -0.5 -0.3 0\nv 0 -0.3 0\nv 0 0.3 0\nv -0.5 0.3 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                    "f 1/1 2/2 3/3 4/4\no part_02\nv 0 -0.3 0\nv 0.5 -0.3 0\nv 0.5 0.3 0\nv 0 0.3 0\n"
                    "f 5/1 6/2 7/3 8/4\n")
    albedo = tmp_path / "albedo.png"
    cv2.imwrite(str(albedo), np.full((4, 4, 3), 128, np.uint8))
    hdri = tmp_path / "sky.hdr"
    cv2.imwrite(str(hdri), np.ones((8, 16, 3), np.float32))
    part = {"albedo": str(albedo), "roughness": 0.5, "metallic": 0.0, "normal": None, "uv_scale": 1.0}
    desc = {"stem": "t", "mesh": str(mesh), "resolution": 32, "samples": 2, "seed": 1,
            "camera": {"position": [0, 0, 2], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 50},
            "hdri": {"path": str(hdri), "rotation": 0.0, "strength": 1.0},
            "parts": [{**part, "object": "part_01", "index": 1}, {**part, "object": "part_02", "index": 2}],
            "outputs": {"beauty": str(tmp_path / "b.png"), "mask": str(tmp_path / "m.png")}}
    (tmp_path / "s.json").write_text(json.dumps(desc))
    subprocess.run(["blender", "-b", "--factory-startup", "-t", "1", "-P", str(build.BLENDER_SCRIPT), "--",
                    str(tmp_path / "s.json")], check=True, capture_output=True, timeout=120)
    mask = scenes.mask_from_render(tmp_path / "m.png", 2)
    assert set(np.unique(mask)) == {0, 1, 2}
    assert (mask[:, :16] != 2).all() and (mask[:, 16:] != 1).all()  # part 1 left, part 2 right
    beauty = scenes.read_render(tmp_path / "b.png")
    assert (beauty[..., 3][mask > 0] > 0).all() and beauty[0, 0, 3] == 0  # transparent film


def test_report_shares_split_by_the_worlds_own_keys() -> None:
    from types import SimpleNamespace

    from experiments.second_world.report import markdown, shares

    raw = {"exemplars": [{"source_id": "a", "open_library": True}, {"source_id": "b"}, {"source_id": "c"}]}
    truths = {1: SimpleNamespace(stem="a", in_collection=True), 2: SimpleNamespace(stem="b", in_collection=False),
              3: SimpleNamespace(stem="c", in_collection=True)}
    assert shares(raw, truths) == {"all": {1, 2, 3}, "open library": {1}, "library materials": {2, 3},
                                   "shape in collection": {1, 3}, "shape held out": {2}}
    assert markdown([{"x": 1}], ["x"]).splitlines() == ["| x |", "|---|", "| 1 |"]
