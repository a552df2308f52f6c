"""`evaluation/groundtruth.py`: the documented ground-truth file read into typed records, with
one message per bad entry (skipped) and an error only for a file that is not this format at all."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from photoshape_flow.evaluation.groundtruth import (
    CameraTruth,
    GroundTruthError,
    ItemRef,
    LightingTruth,
    PartTruth,
    parse_groundtruth_data,
    read_groundtruth_file,
)

PARTS = {"seat": {"material": "oak", "substance": "wood"}, "legs": {"material": "steel", "substance": "metal"}}


def entry(**changes: Any) -> dict[str, Any]:
    """A valid entry (no optional field) with `changes` applied; a value of None removes the key."""
    base: dict[str, Any] = {"source": "photos", "source_id": "p1", "shape": {"source": "cat", "source_id": "chair"},
                            "parts": PARTS}
    base.update(changes)
    return {k: v for k, v in base.items() if v is not None}


def parse(*entries: Any, root: Path = Path("/gt")) -> Any:
    return parse_groundtruth_data({"format": "photoshape-groundtruth", "version": 2, "exemplars": list(entries)},
                                  root)


def test_a_full_entry_becomes_typed_records() -> None:
    """Every field of the documented entry, the mask path resolved against the file's folder, unknown
    keys kept aside (the demo's own fields), the camera's optional fields optional."""
    gt = parse(entry(in_collection=False, camera={"azimuth": 1.5, "elevation": 0.25, "fov": 40},
                     mask={"path": "masks/p1.png", "values": {"1": "seat", "2": "legs"}}, note="kept"))
    assert gt.problems == ()
    (e,) = gt.entries
    assert (e.exemplar, e.shape_ref, e.shape, e.stem) == (ItemRef("photos", "p1"), ItemRef("cat", "chair"),
                                                          "chair", "p1")
    assert e.parts["legs"] == PartTruth("legs", "steel", "metal")
    assert e.camera == CameraTruth(1.5, 0.25, None, 40.0)
    assert e.mask is not None and e.mask.path == Path("/gt/masks/p1.png") and e.mask.kind == "part"
    assert e.part_names == {1: "seat", 2: "legs"}
    assert e.in_collection is False and e.extra == {"note": "kept"}
    # the minimal entry: no camera, no mask, membership decided later against the database
    (minimal,) = parse(entry(source=None, shape={"source_id": "chair"})).entries
    assert minimal.exemplar == ItemRef(None, "p1") and minimal.shape_ref == ItemRef(None, "chair")
    assert (minimal.camera, minimal.mask, minimal.in_collection, minimal.part_names) == (None, None, None, {})


def test_lighting_is_a_file_beside_the_truth_or_a_name() -> None:
    """An envmap file is resolved against the file's folder (what fit's attribution renders with); a
    bare name is kept for the tool to find; rotation and scale default to EnvmapSpec's 0 and 1."""
    (e,) = parse(entry(lighting={"envmap": "envmaps/studio.hdr", "rotation": 1.25, "scale": 0.9})).entries
    assert e.lighting == LightingTruth("envmaps/studio.hdr", 1.25, 0.9, Path("/gt/envmaps/studio.hdr"))
    (named,) = parse(entry(lighting={"envmap": "kloppenheim_06"})).entries
    assert named.lighting == LightingTruth("kloppenheim_06", 0.0, 1.0, None)
    assert "lighting" not in named.extra


def test_a_material_mask_names_materials_not_parts() -> None:
    (e,) = parse(entry(mask={"path": "m.png", "kind": "material", "values": {"3": "velvet"}})).entries
    assert e.mask is not None and e.mask.kind == "material" and e.mask.values == {3: "velvet"}
    assert e.part_names == {}  # says nothing about parts: no part-label accuracy from it


@pytest.mark.parametrize(("bad", "reason"), [
    ("a string", "the entry must be an object"),
    (entry(source_id=""), "source_id must be a non-empty string"),
    (entry(source_id=7), "source_id must be a non-empty string"),
    (entry(shape="chair"), "shape must be an object"),
    (entry(shape={"source": "cat"}), "shape.source_id must be a non-empty string"),
    (entry(parts=None), "parts must be an object"),
    (entry(parts=[]), "parts must be an object"),
    (entry(parts={}), "parts is empty"),
    (entry(parts={"seat": {"material": "oak"}}), "parts.seat.substance must be a non-empty string"),
    (entry(in_collection="no"), "in_collection must be true or false"),
    (entry(camera={"azimuth": "0", "elevation": 0}), "camera.azimuth must be a finite number"),
    (entry(camera={"azimuth": 0}), "camera.elevation must be a finite number"),
    (entry(mask={"path": "m.png", "values": {"1": "arm"}}), "mask values name parts missing from parts: arm"),
    (entry(mask={"path": "m.png", "values": {"0": "seat"}}), "must lie in 1..65535"),
    (entry(mask={"path": "m.png", "values": {"x": "seat"}}), "'x' is not a pixel value"),
    (entry(mask={"path": "m.png", "values": {}}), "mask.values is empty"),
    (entry(mask={"path": "m.png", "kind": "depth", "values": {"1": "seat"}}), "mask.kind must be one of"),
    (entry(mask={"values": {"1": "seat"}}), "mask.path must be a non-empty string"),
    (entry(lighting={"rotation": 1.0}), "lighting.envmap must be a non-empty string"),
    (entry(lighting={"envmap": "a.hdr", "scale": 0}), "lighting.scale must be positive"),
    (entry(lighting={"envmap": "a.hdr", "rotation": "north"}), "lighting.rotation must be a finite number"),
])
def test_each_bad_entry_gets_one_message_and_the_others_are_kept(bad: Any, reason: str) -> None:
    gt = parse(entry(source_id="good1"), bad, entry(source_id="good2"))
    assert [e.stem for e in gt.entries] == ["good1", "good2"]
    (message,) = gt.problems
    assert message.startswith("exemplars[1]") and reason in message and message.endswith("skipped"), message
    if isinstance(bad, dict) and isinstance(bad.get("source_id"), str) and bad["source_id"]:
        assert "(p1)" in message  # named by its source id too


def test_a_repeated_exemplar_keeps_the_first_entry() -> None:
    gt = parse(entry(), entry(parts={"seat": PARTS["seat"]}))
    assert len(gt.entries) == 1 and len(gt.entries[0].parts) == 2
    assert gt.problems == ("exemplars[1] (photos/p1): the same exemplar as exemplars[0] (photos/p1); skipped",)


@pytest.mark.parametrize(("data", "reason"), [
    ([], "must be a JSON object"),
    ({"version": 1, "exemplars": {}}, "a pre-format demo file: run `photoshape demo` again"),
    ({"format": "other", "version": 2, "exemplars": []}, "\"format\" must be 'photoshape-groundtruth'"),
    ({"format": "photoshape-groundtruth", "version": 3, "exemplars": []}, "version 3 not supported"),
    ({"format": "photoshape-groundtruth", "version": 2, "exemplars": {}}, "\"exemplars\" must be a list"),
])
def test_a_file_that_is_not_this_format_is_one_error(data: Any, reason: str) -> None:
    with pytest.raises(GroundTruthError, match="^/gt") as info:
        parse_groundtruth_data(data, Path("/gt"))
    assert reason in str(info.value)


def test_the_file_is_hashed_as_read_and_bad_json_is_one_error(tmp_path: Path) -> None:
    path = tmp_path / "truth.json"
    path.write_text(json.dumps({"format": "photoshape-groundtruth", "version": 2, "exemplars": [entry()],
                                "license": "CC0-1.0"}))
    gt = read_groundtruth_file(path)
    assert gt.sha256 == hashlib.sha256(path.read_bytes()).hexdigest() and gt.path == path
    assert gt.extra == {"license": "CC0-1.0"} and len(gt.entries) == 1
    path.write_text("{not json")
    with pytest.raises(GroundTruthError, match=f"{path}: not JSON"):
        read_groundtruth_file(path)
    with pytest.raises(GroundTruthError, match="cannot read"):
        read_groundtruth_file(tmp_path / "missing.json")


def test_json_lines_a_header_then_one_entry_per_line(tmp_path: Path) -> None:
    """Blank lines are ignored, a line that is not JSON is one skipped entry, messages name lines."""
    path = tmp_path / "truth.jsonl"
    lines = [json.dumps({"format": "photoshape-groundtruth", "version": 2, "license": "CC0-1.0"}),
             json.dumps(entry(source_id="a")), "", "{not json", json.dumps(entry(source_id="b", parts={}))]
    path.write_text("\n".join(lines) + "\n")
    gt = read_groundtruth_file(path)
    assert [e.stem for e in gt.entries] == ["a"] and gt.entries[0].label == "line 2 (photos/a)"
    assert gt.extra == {"license": "CC0-1.0"}
    assert gt.problems[0].startswith("line 4: not JSON (") and gt.problems[0].endswith("; skipped")
    assert gt.problems[1].startswith("line 5 (b): parts is empty")
    path.write_text("{not a header\n" + lines[1])
    with pytest.raises(GroundTruthError, match="line 1, the header, is not JSON"):
        read_groundtruth_file(path)
    path.write_text(json.dumps({"format": "other", "version": 2}))
    with pytest.raises(GroundTruthError, match="\"format\" must be"):
        read_groundtruth_file(path)
