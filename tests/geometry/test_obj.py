"""The OBJ/MTL reader: material groups as parts, groups kept, defaults, and bad input rejected."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from tests.geometry.makers import write_chair_obj

from photoshape_flow.geometry.mtl import parse_mtl, roughness_from_ns, texture_filename
from photoshape_flow.geometry.obj import parse_obj, referenced_files
from photoshape_flow.geometry.raw import BadShapeError, ShapeTooLargeError


def test_parts_follow_first_usemtl_order_and_merge_repeats(tmp_path: Path) -> None:
    raw = parse_obj(write_chair_obj(tmp_path))
    assert [p.name for p in raw.parts] == ["legs", "seat", "back"]
    legs = raw.parts[0]
    assert len(legs.faces) == 2 * 6 * 2  # two boxes of 6 quads, 2 triangles each
    assert legs.meta["groups"] == {"Legs": 24}
    assert raw.meta["groups"] == ["Legs", "Seat", "Back"]
    assert raw.meta["objects"] == ["Back"]
    assert raw.parts[2].meta["groups"] == {"Back": 12}


def test_mtl_values_become_builtin_materials(tmp_path: Path) -> None:
    raw = parse_obj(write_chair_obj(tmp_path, with_texture=True))
    legs, seat, back = raw.parts
    assert legs.material.albedo == (0.1, 0.1, 0.1)
    assert legs.material.roughness == pytest.approx(math.sqrt(2 / 102))
    assert seat.material.roughness == pytest.approx(1.0)  # Ns 0: fully rough
    assert back.material.roughness == pytest.approx(0.3) and back.material.metallic == 1.0  # Pr/Pm
    assert seat.material.texture_path == (tmp_path / "tex" / "seat.png").resolve()
    assert seat.uvs is not None and legs.uvs is None


def test_java3d_colour_names_without_mtl(tmp_path: Path) -> None:
    obj = tmp_path / "s.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl flltgrey\nf 1 2 3\nusemtl unknownname\nf 3 2 1\n")
    raw = parse_obj(obj)
    assert raw.parts[0].material.albedo == pytest.approx((0.8245, 0.8245, 0.8245))
    assert raw.parts[0].material.extra["origin"] == "java3d-default"
    assert raw.parts[1].material.extra["origin"] == "fallback"


def test_polygons_negative_indices_and_default_part(tmp_path: Path) -> None:
    obj = tmp_path / "p.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\nf -5 -4 -3 -2 -1\n")
    raw = parse_obj(obj)
    assert [p.name for p in raw.parts] == ["default"]
    assert raw.parts[0].faces.shape == (3, 3)  # pentagon -> 3 triangles


def test_edges_written_as_faces_are_skipped_with_a_warning(tmp_path: Path) -> None:
    obj = tmp_path / "e.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\nf 2 3\n")
    raw = parse_obj(obj)
    assert len(raw.parts[0].faces) == 1
    assert any("fewer than 3 vertices" in w for w in raw.warnings)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"", "no faces"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
        (b"v 0 0 0\nv 1 0 0\nf 1 2 3\n", "refers to vertex 3"),
        (b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "non-finite"),
        (b"v 0 0 0\nv 1 0 zz\nv 0 1 0\nf 1 2 3\n", "non-finite"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(40), "binary content"),
    ],
    ids=["empty", "no-faces", "truncated", "nan", "malformed-number", "binary"],
)
def test_bad_obj_is_rejected_with_a_reason(tmp_path: Path, content: bytes, reason: str) -> None:
    obj = tmp_path / "bad.obj"
    obj.write_bytes(content)
    with pytest.raises(BadShapeError, match=reason):
        parse_obj(obj)


def test_face_limit_stops_reading_early(tmp_path: Path) -> None:
    with pytest.raises(ShapeTooLargeError, match="more than 10 faces"):
        parse_obj(write_chair_obj(tmp_path), max_faces=10)


def test_references_outside_the_root_are_not_followed(tmp_path: Path) -> None:
    secret = tmp_path / "secret.mtl"
    secret.write_text("newmtl a\nKd 1 0 0\n")
    model_dir = tmp_path / "model"
    model_dir.mkdir()
    obj = model_dir / "m.obj"
    obj.write_text("mtllib ../secret.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n")
    raw = parse_obj(obj, root=model_dir)
    assert raw.parts[0].material.extra["origin"] == "fallback"
    assert any("not found" in w for w in raw.warnings)
    assert referenced_files(obj, model_dir) == []


def test_referenced_files_lists_mtl_and_textures(tmp_path: Path) -> None:
    obj = write_chair_obj(tmp_path, with_texture=True)
    names = {p.name for p in referenced_files(obj, tmp_path)}
    assert names == {"chair.mtl", "seat.png"}


def test_mtl_helpers() -> None:
    assert texture_filename(["-s", "1", "1", "1", "-o", "0", "0", "my", "tex.png"]) == "my tex.png"
    assert texture_filename(["-clamp", "on", "a\\b.jpg"]) == "a/b.jpg"
    mtl = parse_mtl("newmtl x\nKd 0.5\nTr 0.25\nmap_Kd t.png\n")
    assert mtl["x"].kd == (0.5, 0.5, 0.5) and mtl["x"].opacity == 0.75 and mtl["x"].map_kd == "t.png"
    assert roughness_from_ns(0) == 1.0 and roughness_from_ns(-5) == 1.0
    assert np.isclose(roughness_from_ns(998), math.sqrt(2 / 1000))
