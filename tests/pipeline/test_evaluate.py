"""`pipeline/evaluate.py` (`photoshape eval`): every figure it publishes, checked on a tiny, fully
controlled database against a value worked out by hand.

The scene: one chair shape with six parts and photos whose ground truth is drawn below, character by
character, in the stored (8 x 8) exemplar frame. The demo's mask holds its own values (not part
indices) and sits inside a larger native frame, so the exemplar's crop must be applied. Every
stage's expected value is derived in the comment next to its assertion.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import sqlalchemy as sa
from sqlalchemy.orm import Session
from tests.conftest import ingest_tiny_demo
from tests.pipeline.aligned import plant_true_pair

from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.evaluation.groundtruth import TruthEntry, read_groundtruth_file
from photoshape_flow.scoring import evaluate as ev
from photoshape_flow.scoring import rerender_eval, truths
from photoshape_flow.scoring.evaluate import Metric
from photoshape_flow.scoring.groundtruth_match import match_groundtruth
from photoshape_flow.store import BlobStore

# ground-truth parts of the photos: character -> (part name, material, substance)
GT_PARTS = {
    "S": ("seat", "red_leather", "leather"),
    "B": ("back", "blue_leather", "leather"),
    "L": ("leg_l", "walnut", "wood"),
    "R": ("leg_r", "walnut", "wood"),
}
MASK_VALUE = {"S": 7, "B": 5, "L": 9, "R": 3}  # what the demo's part mask holds for each part
MATERIALS = {"red_leather": "leather", "blue_leather": "leather", "walnut": "wood", "oak": "wood",
             "steel": "metal", "grey_fabric": "fabric"}
SHAPE_PARTS = {1: "seat", 2: "back", 3: "legs", 4: "cushion", 5: "hidden", 6: "apron"}
CROP = {"x0": 2, "y0": 1, "side": 8}  # where the stored 8 x 8 frame lies in the 10 x 12 native mask

# The main photo's ground truth and the pair's CRF part map (shape part indices), pixel for pixel:
#   part 1: 8 px of seat                          -> seat (red_leather, leather)
#   part 2: 8 px of back                          -> back (blue_leather, leather)
#   part 3: 3 leg_l + 3 leg_r + 4 seat            -> walnut 6 > red_leather 4; wood 6 > leather 4
#           (the single part covering most is the seat: a majority over parts would say red_leather)
#   part 6: 4 leg_l + 3 seat + 3 back             -> walnut 4 > 3, 3; but leather 6 > wood 4
#   part 4: 3 back + 5 background                 -> mostly background: not scored
#   part 5: no pixels                             -> not scored
TRUTH = (
    "SSSSSSSS",
    "BBBBBBBB",
    "LLLRRRSS",
    "SSLLLLSS",
    "SBBBBBB.",
    "....SSSS",
    "........",
    "........",
)
PART_MAP = (
    "11111111",
    "22222222",
    "33333333",
    "33666666",
    "66664444",
    "44440000",
    "00000000",
    "00000000",
)
ALL_SEAT = ("SSSSSSSS",) * 4 + ("........",) * 4
TOP_HALF = ("11111111",) * 4 + ("00000000",) * 4
EMPTY_MAP = ("00000000",) * 8
GREY = 100  # every stored exemplar photo is this flat grey


def truth_grid(rows: tuple[str, ...]) -> np.ndarray:
    """Stored-frame labels as `truth_labels` numbers them: 1 + index of the part name, sorted."""
    names = sorted(name for name, _, _ in GT_PARTS.values())
    lut = {c: names.index(name) + 1 for c, (name, _, _) in GT_PARTS.items()}
    return np.array([[lut.get(c, 0) for c in row] for row in rows], np.int32)


def part_grid(rows: tuple[str, ...]) -> np.ndarray:
    return np.array([[int(c) for c in row] for row in rows], np.uint8)


def native_mask(rows: tuple[str, ...]) -> np.ndarray:
    """The demo's mask in the native 10 x 12 frame; outside the crop it is all seat (never counted)."""
    native = np.full((10, 12), MASK_VALUE["S"], np.uint8)
    stored = np.array([[MASK_VALUE.get(c, 0) for c in row] for row in rows], np.uint8)
    native[CROP["y0"]:CROP["y0"] + 8, CROP["x0"]:CROP["x0"] + 8] = stored
    return native


def write_groundtruth(root: Path, photos: dict[str, tuple[str, ...]], *, shape: str = "chair",
                      in_collection: dict[str, bool] | None = None) -> Path:
    """groundtruth.json (docs/evaluation.md, version 2) and the photos' part masks under `root`."""
    (root / "masks").mkdir(parents=True, exist_ok=True)
    exemplars = []
    for stem, rows in photos.items():
        cv2.imwrite(str(root / "masks" / f"{stem}.png"), native_mask(rows))
        exemplars.append({
            "source_id": stem, "shape": {"source_id": shape},
            "in_collection": (in_collection or {}).get(stem, True),
            "camera": {"azimuth": 0.0, "elevation": 0.2, "distance": 2.0, "fov": 50.0},
            "parts": {name: {"material": mat, "substance": sub} for name, mat, sub in GT_PARTS.values()},
            "mask": {"path": f"masks/{stem}.png", "kind": "part",
                     "values": {str(MASK_VALUE[c]): name for c, (name, _, _) in GT_PARTS.items()}},
        })
    path = root / "groundtruth.json"
    path.write_text(json.dumps({"format": "photoshape-groundtruth", "version": 2, "exemplars": exemplars}))
    return path


def entry_of(path: Path, stem: str) -> TruthEntry:
    """The parsed entry of one photo (no database)."""
    return next(e for e in read_groundtruth_file(path).entries if e.stem == stem)


@dataclass
class Scene:
    groundtruth: Path
    shape: int = 0
    parts: dict[int, int] = field(default_factory=dict)  # part index -> part id
    materials: dict[str, int] = field(default_factory=dict)  # name -> id
    exemplars: dict[str, int] = field(default_factory=dict)  # stem -> id
    pairs: dict[str, int] = field(default_factory=dict)  # stem -> pair id


def build_scene(url: str, store: BlobStore, root: Path, photos: dict[str, tuple[str, ...]],
                part_maps: dict[str, tuple[str, ...]], **gt: Any) -> Scene:
    """The chair, the materials, one exemplar per photo and one aligned pair per part map."""
    scene = Scene(write_groundtruth(root, photos, **gt))
    with session_scope(url) as session:
        shape = m.Shape(source="t", source_id="chair")
        session.add(shape)
        session.flush()
        scene.shape = shape.id
        for index, name in SHAPE_PARTS.items():
            part = m.Part(shape_id=shape.id, index=index, name=name)
            session.add(part)
            session.flush()
            scene.parts[index] = part.id
        for name, substance in MATERIALS.items():
            material = m.Material(name=name, substance=substance)
            session.add(material)
            session.flush()
            scene.materials[name] = material.id
        for stem, rows in photos.items():
            fg = (truth_grid(rows) > 0).astype(np.uint8) * 255
            exemplar = m.Exemplar(source="demo", source_id=stem, size=8, meta={"crop": dict(CROP)},
                                  image_blob=store.put_image(np.full((8, 8, 3), GREY, np.uint8)),
                                  mask_blob=store.put_image(fg))
            session.add(exemplar)
            session.flush()
            scene.exemplars[stem] = exemplar.id
        for rank, (stem, rows) in enumerate(part_maps.items(), start=1):
            scene.pairs[stem] = add_pair(session, store, shape.id, scene.exemplars[stem], part_grid(rows), rank)
    return scene


def add_pair(session: Session, store: BlobStore, shape_id: int, exemplar_id: int, part_map: np.ndarray,
             rank: int = 1, *, exemplar_rank: int | None = 1, exclude: bool = False,
             alignment_status: str = "ok") -> int:
    pair = m.Pair(shape_id=shape_id, exemplar_id=exemplar_id, rank=rank, exemplar_rank=exemplar_rank,
                  distance=1.0, azimuth=0.0, elevation=0.2, fov=50.0, camera_distance=2.0, exclude=exclude)
    session.add(pair)
    session.flush()
    session.add(m.Alignment(pair_id=pair.id, method="flow-crf", status=alignment_status,
                            crf_blob=store.put_image(part_map)))
    return pair.id


def add_substances(url: str, scene: Scene, stem: str, predicted: dict[int, str | None]) -> None:
    """Part substances of a pair (None: the part was not observed)."""
    with session_scope(url) as session:
        session.add_all([
            m.PartSubstance(pair_id=scene.pairs[stem], part_id=scene.parts[index], observed=sub is not None,
                            substance=sub)
            for index, sub in predicted.items()
        ])


def add_assignments(url: str, scene: Scene, stem: str, method_key: str,
                    ranked: dict[int, list[str | None]]) -> None:
    """Ranked materials per part index (None: no material, as the builtin method stores)."""
    with session_scope(url) as session:
        for index, names in ranked.items():
            for rank, name in enumerate(names, start=1):
                session.add(m.Assignment(
                    pair_id=scene.pairs[stem], part_id=scene.parts[index], method=method_key.split(":")[0],
                    method_key=method_key, rank=rank, material_id=None if name is None else scene.materials[name]))


def truths_of(url: str, scene: Scene) -> dict[int, TruthEntry]:
    with session_scope(url) as session:
        return match_groundtruth(session, read_groundtruth_file(scene.groundtruth)).truths


def by_name(metrics: list[Metric]) -> dict[tuple[str, str], tuple[float | None, int | None]]:
    return {(x.method, x.metric): (x.value, x.count) for x in metrics}


@pytest.fixture
def scene(db_url: str, store: BlobStore, tmp_path: Path) -> Scene:
    """The main photo with its pair (rank 1), substances and three methods' assignments."""
    made = build_scene(db_url, store, tmp_path / "demo", {"photo": TRUTH}, {"photo": PART_MAP})
    add_substances(db_url, made, "photo", {1: "leather", 2: "fabric", 3: "wood", 4: "wood", 5: None, 6: "leather"})
    add_assignments(db_url, made, "photo", "classifier:1", {
        1: ["red_leather", "oak"],
        2: ["walnut", "steel", "grey_fabric", "oak", "red_leather", "blue_leather"],  # the truth 6th
        3: ["oak", "walnut"],
        4: ["steel"],
        5: ["steel"],
        6: ["red_leather", "walnut"],
    })
    add_assignments(db_url, made, "photo", "color-match", {
        1: ["red_leather"], 2: ["blue_leather"], 3: ["walnut"], 4: ["steel"], 6: ["walnut"]})
    add_assignments(db_url, made, "photo", "builtin", {i: [None] for i in SHAPE_PARTS})
    return made


# --- ground truth in the stored frame and the majority rule -------------------------------------------


def test_truth_labels_apply_the_crop_and_the_name_table(tmp_path: Path) -> None:
    """The demo's mask values (7, 5, 9, 3) and its native frame must not leak into the labels."""
    truth = entry_of(write_groundtruth(tmp_path, {"photo": TRUTH}), "photo")
    labels, mats, subs = truths.truth_labels(truth, m.Exemplar(size=8, meta={"crop": dict(CROP)}))
    np.testing.assert_array_equal(labels, truth_grid(TRUTH))
    # sorted names: back, leg_l, leg_r, seat
    assert mats == ["blue_leather", "walnut", "walnut", "red_leather"]
    assert subs == ["leather", "wood", "wood", "leather"]
    # a stored exemplar of 16 px: every label doubled (nearest neighbour never invents a label)
    big, _, _ = truths.truth_labels(truth, m.Exemplar(size=16, meta={"crop": dict(CROP)}))
    np.testing.assert_array_equal(big, np.kron(truth_grid(TRUTH), np.ones((2, 2), np.int32)))


def test_truth_labels_without_a_crop_use_the_whole_native_frame(tmp_path: Path) -> None:
    """No crop recorded: the square of the native frame's longer side, padded with background."""
    truth = entry_of(write_groundtruth(tmp_path, {"photo": TRUTH}), "photo")
    labels, _, _ = truths.truth_labels(truth, m.Exemplar(size=12, meta={}))
    assert labels.shape == (12, 12)
    assert (labels[10:] == 0).all()  # rows 10, 11 lie below the 10-row native mask
    seat = sorted(n for n, _, _ in GT_PARTS.values()).index("seat") + 1
    assert (labels[0] == seat).all()  # the native frame's top row is all seat
    np.testing.assert_array_equal(labels[1:9, 2:10], truth_grid(TRUTH))


@pytest.mark.parametrize(("values", "expected"), [
    ([], None),                  # no pixels at all
    ([0, 0, 0, 1, 1], None),     # 2 of 5 labelled: mostly background
    ([0, 0, 2, 2], 2),           # exactly half labelled counts
    ([1, 1, 2, 2, 2, 0], 2),     # plurality among the labels, background ignored
    ([3, 3, 1, 1], 1),           # a tie goes to the lower label
    ([0, 4], 4),                 # labels 1..3 absent
])
def test_majority(values: list[int], expected: int | None) -> None:
    """The rule that decides which ground-truth label a part is scored against."""
    labels = np.array(values + [5], np.int64)  # one pixel outside the mask, never counted
    mask = np.array([True] * len(values) + [False])
    assert truths.majority_label(labels, mask) == expected


def test_merge_labels_joins_parts_of_one_material() -> None:
    """Two legs of one walnut become one label, so together they can outvote a larger seat."""
    labels = np.array([[0, 1, 2, 3, 4]])
    merged, names = truths.merge_labels(labels, ["blue_leather", "walnut", "walnut", "red_leather"])
    assert names == ["blue_leather", "red_leather", "walnut"]
    np.testing.assert_array_equal(merged, [[0, 1, 3, 3, 2]])


# --- substances ------------------------------------------------------------------------------------


def test_substance_accuracy_scores_observed_parts_against_the_majority_substance(
    db_url: str, store: BlobStore, scene: Scene
) -> None:
    """Parts 1 (leather), 3 (wood) and 6 (leather) right, part 2 (fabric for leather) wrong; part 4 is
    mostly background and part 5 unobserved, so neither counts: 3 / 4."""
    truths = truths_of(db_url, scene)
    with session_scope(db_url) as session:
        (metric,) = ev.evaluate_substances(session, store, truths)
    assert metric == Metric("substances", "substance-network", "part_substance_accuracy", 0.75, 4)


def test_substance_accuracy_skips_excluded_pairs_and_failed_alignments(
    db_url: str, store: BlobStore, scene: Scene
) -> None:
    """A pair dropped by a later coarse alignment keeps its old rows; neither it nor a pair whose
    alignment failed may move the figure (their predictions are all wrong: 3 / 4 would drop)."""
    write_groundtruth(scene.groundtruth.parent, {"photo": TRUTH, "photo2": ALL_SEAT, "photo3": ALL_SEAT})
    with session_scope(db_url) as session:
        for stem, kwargs in (("photo2", {"exclude": True}), ("photo3", {"alignment_status": "failed"})):
            exemplar = m.Exemplar(source="demo", source_id=stem, size=8, meta={"crop": dict(CROP)})
            session.add(exemplar)
            session.flush()
            scene.pairs[stem] = add_pair(session, store, scene.shape, exemplar.id, part_grid(TOP_HALF), 2,
                                         **kwargs)
    for stem in ("photo2", "photo3"):
        add_substances(db_url, scene, stem, {1: "metal"})
        add_assignments(db_url, scene, stem, "color-match", {1: ["steel"]})
    truths = truths_of(db_url, scene)
    assert len(truths) == 3
    with session_scope(db_url) as session:
        (metric,) = ev.evaluate_substances(session, store, truths)
        inference = by_name(ev.evaluate_inference(session, store, truths, rerender_max_pairs=0))
    assert (metric.value, metric.count) == (0.75, 4)
    assert inference[("color-match", "material_top1")] == (1.0, 4)


def test_substance_accuracy_without_scorable_parts_is_none(db_url: str, store: BlobStore, tmp_path: Path) -> None:
    """No observed part over ground-truth pixels: no figure (None), never a 0 / 0."""
    made = build_scene(db_url, store, tmp_path / "demo", {"photo": TRUTH}, {"photo": EMPTY_MAP})
    add_substances(db_url, made, "photo", {1: "leather"})
    with session_scope(db_url) as session:
        (metric,) = ev.evaluate_substances(session, store, truths_of(db_url, made))
    assert (metric.value, metric.count) == (None, 0)


# --- inference: materials and substances ---------------------------------------------------------


def test_material_top1_top5_and_substance_accuracy(db_url: str, store: BlobStore, scene: Scene) -> None:
    """Truth per scored part: 1 red_leather/leather, 2 blue_leather/leather, 3 walnut/wood,
    6 walnut/leather (walnut is the material covering most, leather the substance covering most).

    classifier: 1 right at rank 1; 2 right only at rank 6 (outside the top 5); 3 and 6 right at rank 2
    -> top-1 1/4, top-5 3/4; the rank-1 substances leather, wood, wood, leather -> 3/4 right.
    color-match: every rank-1 material right -> 4/4; walnut is wood, part 6 is leather -> 3/4.
    builtin: no material at all -> 0/4 and no substance figure.
    """
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths_of(db_url, scene), rerender_max_pairs=0))
    assert metrics == {
        ("builtin", "material_top1"): (0.0, 4),
        ("builtin", "material_top5"): (0.0, 4),
        ("classifier:1", "material_top1"): (0.25, 4),
        ("classifier:1", "material_top5"): (0.75, 4),
        ("classifier:1", "substance_accuracy"): (0.75, 4),
        ("color-match", "material_top1"): (1.0, 4),
        ("color-match", "material_top5"): (1.0, 4),
        ("color-match", "substance_accuracy"): (0.75, 4),
        # every other method minus ours (the newest classifier), over the same exemplars
        ("builtin", "material_top1_vs_ours"): (-0.25, 4),
        ("builtin", "material_top5_vs_ours"): (-0.75, 4),
        ("color-match", "material_top1_vs_ours"): (0.75, 4),
        ("color-match", "material_top5_vs_ours"): (0.25, 4),
        ("color-match", "substance_accuracy_vs_ours"): (0.0, 4),
    }


def test_inference_figures_are_means_over_parts_of_all_pairs(db_url: str, store: BlobStore, tmp_path: Path) -> None:
    """Pooled over parts, not averaged per pair: 3 right of 5 is 0.6 (per-pair means give 0.75)."""
    made = build_scene(db_url, store, tmp_path / "demo", {"photo": TRUTH, "photo2": ALL_SEAT},
                       {"photo": PART_MAP, "photo2": TOP_HALF})
    add_assignments(db_url, made, "photo", "color-match",
                    {1: ["red_leather"], 2: ["blue_leather"], 3: ["oak"], 6: ["oak"]})  # 2 of 4
    add_assignments(db_url, made, "photo2", "color-match", {1: ["red_leather"]})  # 1 of 1
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths_of(db_url, made), rerender_max_pairs=0))
    assert metrics[("color-match", "material_top1")] == (pytest.approx(0.6), 5)


def test_inference_figures_carry_an_interval_over_exemplars(db_url: str, store: BlobStore, tmp_path: Path) -> None:
    """Two photos, one 2-of-4 and one 1-of-1: the interval is the means of the exemplar resamples
    (all photo: 0.5, all photo2: 1.0), so it spans 0.5 to 1.0 around the pooled 0.6; one photo gives none."""
    made = build_scene(db_url, store, tmp_path / "demo", {"photo": TRUTH, "photo2": ALL_SEAT},
                       {"photo": PART_MAP, "photo2": TOP_HALF})
    add_assignments(db_url, made, "photo", "color-match",
                    {1: ["red_leather"], 2: ["blue_leather"], 3: ["oak"], 6: ["oak"]})
    add_assignments(db_url, made, "photo2", "color-match", {1: ["red_leather"]})
    with session_scope(db_url) as session:
        truths = truths_of(db_url, made)
        both = {(x.method, x.metric): x for x in ev.evaluate_inference(session, store, truths, rerender_max_pairs=0)}
        one_id = next(iter(truths))
        one = {(x.method, x.metric): x for x in
               ev.evaluate_inference(session, store, {one_id: truths[one_id]}, rerender_max_pairs=0)}
    top1 = both[("color-match", "material_top1")]
    assert (top1.low, top1.high) == (pytest.approx(0.5), pytest.approx(1.0))
    assert one[("color-match", "material_top1")].low is None


def test_exemplars_outside_the_source_or_not_ok_have_no_truth(db_url: str, store: BlobStore, scene: Scene) -> None:
    """Exemplars match the ground truth by source id, within the asked source, when ingested fine."""
    gt = read_groundtruth_file(scene.groundtruth)
    with session_scope(db_url) as session:
        session.add(m.Exemplar(source="demo", source_id="not_in_groundtruth"))
        assert set(match_groundtruth(session, gt, "demo").truths) == {scene.exemplars["photo"]}
        assert match_groundtruth(session, gt, "elsewhere").truths == {}
        session.get(m.Exemplar, scene.exemplars["photo"]).status = "rejected"
        assert match_groundtruth(session, gt, None).truths == {}


# --- entries without a mask, material masks --------------------------------------------------------


def rewrite_entries(path: Path, edit: Any) -> None:
    """Apply `edit(entries)` to the ground-truth file in place."""
    data = json.loads(path.read_text())
    edit(data["exemplars"])
    path.write_text(json.dumps(data))


def test_without_a_mask_parts_are_scored_by_name_on_the_true_shape_only(
    db_url: str, store: BlobStore, tmp_path: Path
) -> None:
    """No mask: each of the chair's six parts is scored against the entry's part of the same name (all
    of them: visibility is unknown), and only on pairs of the chair. Ours: seat, legs, hidden and
    apron right, back only 2nd (top-5), cushion wrong -> top-1 4/6, top-5 5/6; the first choice's
    substance: back (walnut: wood for leather) and cushion (steel: metal for fabric) wrong -> 4/6.
    'other' shows the chair too but its pair is with a stool: not scored (it would add a 0)."""
    made = build_scene(db_url, store, tmp_path / "demo", {"photo": TRUTH, "other": TRUTH}, {"photo": PART_MAP})
    named = {"seat": "red_leather", "back": "blue_leather", "legs": "walnut", "cushion": "grey_fabric",
             "hidden": "steel", "apron": "oak"}

    def drop_masks(entries: list[dict[str, Any]]) -> None:
        for e in entries:
            del e["mask"]
            e["parts"] = {n: {"material": mat, "substance": MATERIALS[mat]} for n, mat in named.items()}

    rewrite_entries(made.groundtruth, drop_masks)
    with session_scope(db_url) as session:
        stool = m.Shape(source="t", source_id="stool")
        session.add(stool)
        session.flush()
        session.add(m.Part(shape_id=stool.id, index=1, name="seat"))
        made.pairs["other"] = add_pair(session, store, stool.id, made.exemplars["other"], part_grid(PART_MAP))
    add_assignments(db_url, made, "photo", "classifier:1", {
        1: ["red_leather"], 2: ["walnut", "blue_leather"], 3: ["walnut"], 4: ["steel"], 5: ["steel"], 6: ["oak"]})
    with session_scope(db_url) as session:
        session.add(m.Assignment(pair_id=made.pairs["other"], part_id=session.execute(
            sa.select(m.Part.id).where(m.Part.shape_id == stool.id)).scalar_one(), method="classifier",
            method_key="classifier:1", rank=1, material_id=made.materials["steel"]))
    truths = truths_of(db_url, made)
    assert len(truths) == 2
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths, rerender_max_pairs=0))
    assert metrics[("classifier:1", "material_top1")] == (pytest.approx(4 / 6), 6)
    assert metrics[("classifier:1", "material_top5")] == (pytest.approx(5 / 6), 6)
    assert metrics[("classifier:1", "substance_accuracy")] == (pytest.approx(4 / 6), 6)


def test_a_material_mask_scores_like_the_part_mask_it_summarises(db_url: str, store: BlobStore, scene: Scene) -> None:
    """The main photo's parts relabelled by material (seat red_leather, back blue_leather, both legs
    walnut) must give every figure the part mask gives: scoring already merges parts of one material.
    Substances come from the material table; an unknown material in a mask skips its entry."""
    with session_scope(db_url) as session:
        by_part = by_name(ev.evaluate_inference(session, store, truths_of(db_url, scene), rerender_max_pairs=0))
        by_part_substances = ev.evaluate_substances(session, store, truths_of(db_url, scene))

    def to_materials(entries: list[dict[str, Any]]) -> None:
        (e,) = entries
        names = {name: mat for name, mat, _ in GT_PARTS.values()}
        e["mask"] = {"path": e["mask"]["path"], "kind": "material",
                     "values": {v: names[part] for v, part in e["mask"]["values"].items()}}
        entries.append(dict(e, source_id="photo2", mask=dict(e["mask"], values={"1": "nope"})))

    rewrite_entries(scene.groundtruth, to_materials)
    with session_scope(db_url) as session:
        matched = match_groundtruth(session, read_groundtruth_file(scene.groundtruth))
        (truth,) = matched.truths.values()
        assert truth.material_substances == {"red_leather": "leather", "blue_leather": "leather", "walnut": "wood"}
        assert truth.part_names == {}  # no part-label accuracy from a material mask
        assert matched.problems == ("exemplars[1] (photo2): exemplar photo2 is not ingested (or not ok); "
                                    "unknown materials: nope; skipped",)  # every reason, one line
        assert by_name(ev.evaluate_inference(session, store, matched.truths, rerender_max_pairs=0)) == by_part
        assert ev.evaluate_substances(session, store, matched.truths) == by_part_substances


def test_a_mask_not_in_the_photos_frame_skips_its_entry(db_url: str, store: BlobStore, scene: Scene) -> None:
    """The 12 x 10 mask fits a photo ingested at 12 x 10; against 16 x 10 every crop would be shifted."""
    for size, problems in (((12, 10), ()), ((16, 10), (
            f"exemplars[0] (photo): mask {scene.groundtruth.parent / 'masks' / 'photo.png'} is 12x10 but the photo "
            "is 16x10; skipped",))):
        with session_scope(db_url) as session:
            exemplar = session.get(m.Exemplar, scene.exemplars["photo"])
            exemplar.native_width, exemplar.native_height = size
        with session_scope(db_url) as session:
            matched = match_groundtruth(session, read_groundtruth_file(scene.groundtruth))
        assert matched.problems == problems and len(matched.truths) == 1 - len(problems)


# --- re-render error ---------------------------------------------------------------------------------


def flat(value: tuple[int, int, int] | int, size: int = 16) -> np.ndarray:
    return np.broadcast_to(np.array(value, np.uint8), (size, size, 3)).copy()


def luminance_ssim(a: float, b: float) -> float:
    """SSIM of two flat images (no variance): the luminance term alone, C1 = (0.01 * data range)^2."""
    c1 = 0.01**2
    return (2 * a * b + c1) / (a * a + b * b + c1)


def test_rerender_error_of_identical_images() -> None:
    image = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    rmse, ssim = rerender_eval.rerender_error(image, image.copy(), np.ones((16, 16), bool))
    assert rmse == 0.0 and ssim == pytest.approx(1.0)


def test_rerender_error_of_flat_images() -> None:
    """150 against 100 everywhere: RMSE 50/255; SSIM the luminance term of 150/255 and 100/255."""
    rmse, ssim = rerender_eval.rerender_error(flat(150), flat(100), np.ones((16, 16), bool))
    assert rmse == pytest.approx(50 / 255)
    assert ssim == pytest.approx(luminance_ssim(150 / 255, 100 / 255))  # 0.9231


def test_rerender_rmse_averages_over_the_three_channels() -> None:
    """Only red off by 51 (0.2): sqrt((0.2^2 + 0 + 0) / 3), not 0.2 (a per-pixel norm) or the grey error."""
    rmse, _ = rerender_eval.rerender_error(flat((151, 100, 100)), flat(100), np.ones((16, 16), bool))
    assert rmse == pytest.approx(0.2 / math.sqrt(3))


def test_rerender_error_counts_only_the_exemplars_mask() -> None:
    """Pixels outside the mask, farther than the 7 x 7 SSIM window reaches, change nothing."""
    render, photo = flat(100), flat(100)
    render[:, 10:] = 250  # columns 10..15 differ
    mask = np.zeros((16, 16), bool)
    mask[:, :6] = True  # columns 0..5: the window (radius 3) stops at column 8
    assert rerender_eval.rerender_error(render, photo, mask) == (0.0, pytest.approx(1.0))
    rmse, _ = rerender_eval.rerender_error(render, photo, np.ones((16, 16), bool))
    assert rmse == pytest.approx(math.sqrt(6 / 16) * 150 / 255)  # 6 of 16 columns off by 150


def test_rerender_error_of_an_empty_mask_is_nan() -> None:
    rmse, ssim = rerender_eval.rerender_error(flat(150), flat(100), np.zeros((16, 16), bool))
    assert math.isnan(rmse) and math.isnan(ssim)


class FakeRerenderer:
    """Stands in for Mitsuba: a flat render whose grey level is set per pair; records what it was asked."""

    level: dict[int, int] = {}
    calls: list[tuple[int, dict[int, int | None]]] = []

    def __init__(self, store: BlobStore, size: int, spp: int) -> None:
        self.size = size

    def set_envmap(self, envmap: Any) -> None:
        pass

    def render(self, session: Session, pair: m.Pair, materials: dict[int, int | None],
               refinements: dict[int, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:
        FakeRerenderer.calls.append((pair.id, dict(materials)) if refinements is None
                                    else (pair.id, dict(materials), dict(refinements)))
        if pair.id not in self.level:
            raise RuntimeError("the shape is not visible")
        brighter = 30 if refinements else 0  # a refined render is closer to nothing in particular: just different
        return flat(self.level[pair.id] + brighter, self.size), np.ones((self.size, self.size), bool)


def test_rerender_figures_per_method(db_url: str, store: BlobStore, tmp_path: Path,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Re-render error: rank-1 materials, only each exemplar's best shape, at most `rerender_max_pairs`
    pairs per method, a failed render skipped, and the mean over pairs inside each exemplar's mask.

    Pairs a, d, b, c, e (in id order) have flat renders 150, 150, (fails), 200, 150 against the
    grey-100 photos; d is not its exemplar's best shape. With at most 2 pairs: a and c are scored (d is
    skipped, b fails, e comes after the cap) -> RMSE (50 + 100) / 2 / 255, SSIM the mean of the two
    luminance terms; colour-match, with one pair (a) -> 50/255.
    """
    stems = ("a", "d", "b", "c", "e")
    made = build_scene(db_url, store, tmp_path / "demo", dict.fromkeys(stems, ALL_SEAT), {})
    with session_scope(db_url) as session:
        for rank, stem in enumerate(stems, start=1):
            made.pairs[stem] = add_pair(session, store, made.shape, made.exemplars[stem], part_grid(TOP_HALF),
                                        rank, exemplar_rank=2 if stem == "d" else 1)
    for stem in stems:
        add_assignments(db_url, made, stem, "classifier:1", {1: ["red_leather", "oak"], 2: ["steel"]})
    add_assignments(db_url, made, "a", "color-match", {1: ["oak"]})
    FakeRerenderer.level = {made.pairs[k]: level for k, level in (("a", 150), ("d", 150), ("c", 200), ("e", 150))}
    FakeRerenderer.calls = []
    monkeypatch.setattr(rerender_eval, "Rerenderer", FakeRerenderer)
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths_of(db_url, made), rerender_size=8,
                                                rerender_max_pairs=2))
    rank1 = {1: made.materials["red_leather"], 2: made.materials["steel"]}
    assert FakeRerenderer.calls == [(made.pairs["a"], rank1), (made.pairs["a"], {1: made.materials["oak"]}),
                                    (made.pairs["b"], rank1), (made.pairs["c"], rank1)]
    assert metrics[("classifier:1", "rerender_rmse")] == (pytest.approx(150 / 2 / 255), 2)
    ssim, _ = metrics[("classifier:1", "rerender_ssim")]
    assert ssim == pytest.approx((luminance_ssim(150 / 255, GREY / 255) + luminance_ssim(200 / 255, GREY / 255)) / 2)
    assert metrics[("color-match", "rerender_rmse")] == (pytest.approx(50 / 255), 1)
    assert metrics[("classifier:1", "material_top1")] == (1.0, 5)  # every pair's seat is scored, d included


def test_a_nan_rerender_error_is_left_out_of_the_mean(db_url: str, store: BlobStore, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """An exemplar with an empty mask gives NaN: the figure is over the other pairs, and None alone."""
    made = build_scene(db_url, store, tmp_path / "demo", {"a": ALL_SEAT, "b": ALL_SEAT},
                       {"a": TOP_HALF, "b": TOP_HALF})
    with session_scope(db_url) as session:
        session.get(m.Exemplar, made.exemplars["b"]).mask_blob = store.put_image(np.zeros((8, 8), np.uint8))
    add_assignments(db_url, made, "a", "classifier:1", {1: ["red_leather"]})
    add_assignments(db_url, made, "b", "classifier:1", {1: ["red_leather"]})
    add_assignments(db_url, made, "b", "color-match", {1: ["red_leather"]})
    FakeRerenderer.level = {made.pairs["a"]: 150, made.pairs["b"]: 200}
    monkeypatch.setattr(rerender_eval, "Rerenderer", FakeRerenderer)
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths_of(db_url, made), rerender_size=8))
    assert metrics[("classifier:1", "rerender_rmse")] == (pytest.approx(50 / 255), 1)
    assert metrics[("color-match", "rerender_rmse")] == (None, 0)


def test_a_refining_method_is_also_scored_as_refined_on_the_same_pairs(
        db_url: str, store: BlobStore, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Fit's "after refinement" column: a method with refined rank-1 rows gets `rerender_*_refined` over
    the same pairs as `rerender_*`: pair a rendered again with its refinements (flat 150 + 30 against
    grey 100), pair b (no refinement) counted with its selected value; other methods get no such figure,
    and the cap of pairs counts each pair once."""
    made = build_scene(db_url, store, tmp_path / "demo", {"a": ALL_SEAT, "b": ALL_SEAT},
                       {"a": TOP_HALF, "b": TOP_HALF})
    for stem in ("a", "b"):
        add_assignments(db_url, made, stem, "fit:1", {1: ["oak", "red_leather"]})
        add_assignments(db_url, made, stem, "classifier:1", {1: ["red_leather"]})
    tint = {"tint": [1.2, 1.0, 0.8], "roughness_scale": 1.0, "uv_scale": 1.0, "uv_rotation": 0.0}
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Assignment).where(
            m.Assignment.pair_id == made.pairs["a"], m.Assignment.method_key == "fit:1",
            m.Assignment.rank == 1)).scalar_one()
        row.refinement = tint
    FakeRerenderer.level = {made.pairs["a"]: 150, made.pairs["b"]: 200}
    FakeRerenderer.calls = []
    monkeypatch.setattr(rerender_eval, "Rerenderer", FakeRerenderer)
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths_of(db_url, made), rerender_size=8,
                                                rerender_max_pairs=2))
    oak = {1: made.materials["oak"]}
    assert (made.pairs["a"], oak, {1: tint}) in FakeRerenderer.calls
    assert sum(len(c) == 3 for c in FakeRerenderer.calls) == 1  # b is not rendered again
    assert metrics[("fit:1", "rerender_rmse")] == (pytest.approx((50 + 100) / 2 / 255), 2)
    assert metrics[("fit:1", "rerender_rmse_refined")] == (pytest.approx((80 + 100) / 2 / 255), 2)
    assert ("classifier:1", "rerender_rmse_refined") not in metrics
    assert metrics[("classifier:1", "rerender_rmse")][1] == 2


# --- training, pass-through dictionaries, the table ----------------------------------------------


def test_training_reports_each_ok_classifiers_numeric_metrics(db_url: str) -> None:
    """Numbers only (an int becomes a float; booleans, strings and nested values are not figures)."""
    with session_scope(db_url) as session:
        session.add_all([
            m.Classifier(name="r34", kind="material", architecture="resnet34", metrics={
                "val_top1": 0.625, "epochs": 12, "converged": True, "note": "x", "per_class": {"oak": 1.0}}),
            m.Classifier(name="broken", kind="material", architecture="resnet34", status="failed",
                         metrics={"val_top1": 0.1}),
            m.Classifier(name="subs", kind="substance", architecture="resnet18", metrics={"val_accuracy": 0.5}),
        ])
    with session_scope(db_url) as session:
        metrics = ev.evaluate_training(session)
    assert metrics == [
        Metric("training", "material:r34", "val_top1", 0.625),
        Metric("training", "material:r34", "epochs", 12.0),
        Metric("training", "substance:subs", "val_accuracy", 0.5),
    ]


def test_dict_metrics_keep_numbers_pair_counts_and_turn_nan_into_none() -> None:
    values = {"recall@1": 0.5, "recall@1_count": 4, "median_error": float("nan"), "flow_improves": True,
              "label": "x"}
    assert ev._dict_metrics("coarse-alignment", "hog", values) == [
        Metric("coarse-alignment", "hog", "recall@1", 0.5, 4),
        Metric("coarse-alignment", "hog", "recall@1_count", 4.0, None),
        Metric("coarse-alignment", "hog", "median_error", None, None),
    ]


def test_metrics_table_rounds_to_four_places() -> None:
    rows = ev.metrics_table([Metric("s", "m", "a", 2 / 3, 3), Metric("s", "m", "b", None)])
    assert rows == [{"stage": "s", "method": "m", "metric": "a", "value": 0.6667, "count": 3, "95% interval": ""},
                    {"stage": "s", "method": "m", "metric": "b", "value": None, "count": None, "95% interval": ""}]


# --- run_evaluation: every stage stored in the evaluation table --------------------------------------


def stored(url: str) -> dict[tuple[str, str, str, str], tuple[float | None, int | None, dict[str, Any]]]:
    with session_scope(url) as session:
        rows = session.execute(sa.select(m.Evaluation)).scalars().all()
        return {(r.run, r.stage, r.method, r.metric): (r.value, r.count, r.params) for r in rows}


def test_run_evaluation_stores_every_figure_once(db_url: str, store: BlobStore, scene: Scene) -> None:
    """The figures land in `evaluation` keyed by (run, stage, method, metric); a second run of the same
    name updates them instead of adding rows; an unknown source is an error, not an empty run."""
    with session_scope(db_url) as session:
        session.add(m.Classifier(name="r34", kind="material", architecture="resnet34", metrics={"val_top1": 0.5}))
    stages = ("substances", "training", "inference")
    name, metrics = ev.run_evaluation(scene.groundtruth, "t1", stages=stages, rerender_max_pairs=0)
    assert name == "t1" and len(metrics) == 1 + 1 + 8 + 5  # + 5 differences to ours
    rows = stored(db_url)
    params = {"groundtruth": str(scene.groundtruth), "exemplars": 1, "skipped": 0}
    assert rows[("t1", "substances", "substance-network", "part_substance_accuracy")] == (0.75, 4, params)
    assert rows[("t1", "inference", "classifier:1", "material_top5")] == (0.75, 4, params)
    assert rows[("t1", "training", "material:r34", "val_top1")] == (0.5, None, params)
    assert rows[("t1", "inference", "color-match", "material_top1_vs_ours")] == (0.75, 4, params)
    assert len(rows) == len(metrics)
    sha = hashlib.sha256(scene.groundtruth.read_bytes()).hexdigest()
    with session_scope(db_url) as session:  # every figure tagged with the file's hash; the file registered
        assert set(session.execute(sa.select(m.Evaluation.groundtruth_sha256)).scalars()) == {sha}
        registered = session.execute(sa.select(m.GroundTruthFileRow)).scalar_one()
        assert (registered.path, registered.sha256, registered.entries) == (str(scene.groundtruth), sha, 1)
    ev.run_evaluation(scene.groundtruth, "t1", stages=stages, rerender_max_pairs=0)
    assert len(stored(db_url)) == len(metrics)
    default, _ = ev.run_evaluation(scene.groundtruth, stages=["training"])
    assert dt.datetime.strptime(default, "eval-%Y%m%d-%H%M%S")
    with pytest.raises(ValueError, match="no ingested exemplar matches"):
        ev.run_evaluation(scene.groundtruth, "t2", exemplar_source="elsewhere")


def test_run_evaluation_passes_shape_recall_and_part_label_accuracy_through(
    db_url: str, store: BlobStore, tmp_path: Path
) -> None:
    """Coarse and fine alignment are scored by their stages' own functions; evaluate stores them.

    Shape recall: 'photo' finds the chair at rank 2, 'photo2' at rank 1, 'photo3' shows a shape outside
    the collection -> recall@1 1/2, recall@5 2/2 over 2 exemplars.
    Part-label accuracy (over the 43 ground-truth pixels of 'photo'; parts are matched by name, so only
    seat and back can be right): CRF map right on 8 seat + 8 back pixels -> 16/43; the flow map only
    on the seat row -> 8/43; an empty coarse map -> 0.
    """
    from photoshape_flow.alignment.coarse.viewpoint_sets import ensure_viewpoint_set
    from photoshape_flow.alignment.coarse_alignment import CoarseConfig

    photos = {"photo": TRUTH, "photo2": ALL_SEAT, "photo3": ALL_SEAT}
    made = build_scene(db_url, store, tmp_path / "demo", photos, {"photo": PART_MAP},
                       in_collection={"photo3": False})
    flow = part_grid(PART_MAP)
    flow[1:] = 0
    with session_scope(db_url) as session:
        alignment = session.execute(sa.select(m.Alignment)).scalar_one()
        alignment.coarse_blob = store.put_image(np.zeros((8, 8), np.uint8))
        alignment.flow_blob = store.put_image(flow)
        other = m.Shape(source="t", source_id="stool")
        session.add(other)
        session.flush()
        config = CoarseConfig()
        vpset = ensure_viewpoint_set(session, config.viewpoint_set, config.viewpoint_version)
        ranked = {"photo": [other.id, made.shape], "photo2": [made.shape, other.id], "photo3": [other.id]}
        for stem, shapes in ranked.items():
            for rank, shape_id in enumerate(shapes, start=1):
                session.add(m.ExemplarMatch(
                    exemplar_id=made.exemplars[stem], viewpoint_set_id=vpset.id, descriptor=config.hog.name,
                    rank=rank, shape_id=shape_id, view_index=0, distance=float(rank), params_hash="h",
                    searched_at=dt.datetime(2026, 1, 1)))
    _, metrics = ev.run_evaluation(made.groundtruth, "t", stages=["coarse-alignment", "fine-alignment"])
    got = {(x.stage, x.metric): x.value for x in metrics}
    assert got[("coarse-alignment", "recall@1")] == 0.5
    assert got[("coarse-alignment", "recall@5")] == 1.0
    assert got[("coarse-alignment", "n_in_collection")] == 2.0
    recall = next(x for x in metrics if x.metric == "recall@1")  # one hit, one miss: 0 to 1 over exemplars
    assert (recall.low, recall.high, recall.count) == (0.0, 1.0, 2)
    assert got[("fine-alignment", "accuracy_crf")] == pytest.approx(16 / 43)
    assert got[("fine-alignment", "accuracy_flow")] == pytest.approx(8 / 43)
    assert got[("fine-alignment", "accuracy_coarse")] == 0.0
    assert ("fine-alignment", "flow_improves") not in got  # a boolean, not a figure
    assert stored(db_url)[("t", "fine-alignment", "flow-crf", "accuracy_crf")][0] == pytest.approx(16 / 43)


# --- the tiny demo: an oracle scores perfectly ----------------------------------------------------


def test_an_oracle_scores_one_on_the_tiny_demo(tiny_demo: Path, db_url: str, store: BlobStore) -> None:
    """On the demo's real ground truth and ingest crop: the ground truth's own parts as the aligned
    part map, each part given its true material and substance, must score 1 on every figure, with one
    scored part per visible ground-truth part (and the ground truth's foreground must agree with the
    stored exemplar's mask: the crop is applied the way ingest applied it)."""
    from photoshape_flow.align.partmap import exemplar_at

    ingest_tiny_demo(tiny_demo, 128)
    gt = read_groundtruth_file(tiny_demo / "groundtruth.json")
    visible = 0
    with session_scope(db_url) as session:
        matched = match_groundtruth(session, gt, "demo-tiny")
        assert matched.problems == () and len(matched.truths) == len(gt.entries)  # the demo's file is clean
        materials = dict(session.execute(sa.select(m.Material.name, m.Material.id)).all())
        for exemplar_id, truth in matched.truths.items():
            exemplar = session.get(m.Exemplar, exemplar_id)
            labels, mats, subs = truths.truth_labels(truth, exemplar)
            _, fg = exemplar_at(store.load_image(exemplar.image_blob), store.load_image(exemplar.mask_blob),
                                exemplar.size)
            truth_fg = labels > 0
            assert (truth_fg & fg).sum() / (truth_fg | fg).sum() > 0.85, truth.stem  # 0.91 to 0.99 measured
            shape = m.Shape(source="oracle", source_id=truth.stem)
            session.add(shape)
            session.flush()
            pair = m.Pair(shape_id=shape.id, exemplar_id=exemplar_id, rank=1, distance=0.0, azimuth=0.0,
                          elevation=0.0, fov=50.0, camera_distance=2.0)
            session.add(pair)
            session.flush()
            session.add(m.Alignment(pair_id=pair.id, method="flow-crf", crf_blob=store.put_image(
                labels.astype(np.uint8))))
            for index in map(int, np.unique(labels[labels > 0])):
                name, substance = mats[index - 1], subs[index - 1]
                part = m.Part(shape_id=shape.id, index=index, name=f"part{index}")
                session.add(part)
                session.flush()
                session.add_all([
                    m.PartSubstance(pair_id=pair.id, part_id=part.id, substance=substance),
                    m.Assignment(pair_id=pair.id, part_id=part.id, method="oracle", method_key="oracle",
                                 material_id=materials[name]),
                ])
                visible += 1
    _, metrics = ev.run_evaluation(tiny_demo / "groundtruth.json", "oracle", stages=["substances", "inference"],
                                   exemplar_source="demo-tiny", rerender_max_pairs=0)
    assert visible >= len(gt.entries)
    assert by_name(metrics) == {
        ("substance-network", "part_substance_accuracy"): (1.0, visible),
        ("oracle", "material_top1"): (1.0, visible),
        ("oracle", "material_top5"): (1.0, visible),
        ("oracle", "substance_accuracy"): (1.0, visible),
    }
    assert len(stored(db_url)) == 4


@pytest.mark.slow
@pytest.mark.render
def test_rerender_error_with_mitsuba_prefers_the_true_materials(tiny_demo: Path, db_url: str,
                                                                store: BlobStore) -> None:
    """The real re-render path (Mitsuba, zoom, square crop, the exemplar's mask): each in-collection
    photo's own shape at its true camera, rendered with its true materials, is far closer to the photo
    than with a material of another substance on every part (measured RMSE 0.11 against 0.20; SSIM
    0.81 against 0.67); the photo's envmap and degradations are not the studio's, so never zero."""
    pytest.importorskip("mitsuba")
    from photoshape_flow.ingest.ingest import ingest_envmaps

    ingest_tiny_demo(tiny_demo, 64)
    ingest_envmaps([sorted((tiny_demo / "envmaps").glob("studio*"))[0]], isolate=False)
    gt = read_groundtruth_file(tiny_demo / "groundtruth.json")
    pairs = 0
    with session_scope(db_url) as session:
        shapes = {s.source_id: s for s in session.execute(sa.select(m.Shape)).scalars()}
        materials = {x.name: x for x in session.execute(sa.select(m.Material)).scalars()}
        truths = match_groundtruth(session, gt, "demo-tiny").truths
        for exemplar_id, truth in truths.items():
            if not truth.in_collection:
                continue
            shape = shapes[truth.shape]
            pair = plant_true_pair(session, store, shape, exemplar_id, truth)
            for part in shape.parts:
                true = truth.parts[part.name]
                other = min(n for n, x in materials.items() if x.substance != true.substance)
                for key, name in (("true", true.material), ("other", other)):
                    session.add(m.Assignment(pair_id=pair.id, part_id=part.id, method=key, method_key=key,
                                             material_id=materials[name].id))
            pairs += 1
    assert pairs >= 2
    with session_scope(db_url) as session:
        metrics = by_name(ev.evaluate_inference(session, store, truths, rerender_size=64, rerender_spp=4,
                                                relight_max_pairs=None))
    (true_rmse, n), (other_rmse, _) = metrics[("true", "rerender_rmse")], metrics[("other", "rerender_rmse")]
    assert n == pairs
    assert true_rmse is not None and other_rmse is not None
    assert 0.0 < true_rmse < 0.15 and true_rmse < 0.75 * other_rmse
    assert metrics[("other", "rerender_ssim")][0] < metrics[("true", "rerender_ssim")][0] <= 1.0
    assert metrics[("true", "material_top1")][0] == 1.0 and metrics[("other", "material_top1")][0] == 0.0
    # relighting (held-out light, three novel views, the true shape): the true materials render the
    # very image of the truth; another substance's do not
    assert metrics[("true", "relight_rmse")] == (0.0, pairs)
    assert metrics[("other", "relight_rmse")][0] > 0.05
