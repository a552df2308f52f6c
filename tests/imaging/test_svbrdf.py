"""Material folders: map names from common sources, sidecars, conversions, rejections."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tests.geometry.makers import write_png

from photoshape_flow.imaging.svbrdf import BadMaterialError, classify_map, is_material_folder, load_maps, scan_material


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("albedo.jpg", ("albedo", None)),
        ("Wood049_1K-JPG_Color.jpg", ("albedo", None)),  # ambientCG
        ("Wood049_1K-JPG_NormalDX.jpg", ("normal", "dx")),
        ("Wood049_1K-JPG_NormalGL.png", ("normal", "gl")),
        ("Wood049_1K-JPG_Displacement.jpg", ("height", None)),
        ("Metal01_1K_Metalness.jpg", ("metallic", None)),
        ("Wood049_1K-JPG_AmbientOcclusion.jpg", ("ao", None)),
        ("rosewood_veneer1_nor_gl_1k.png", ("normal", "gl")),  # Poly Haven
        ("metal_plate_diff_1k.jpg", ("albedo", None)),
        ("metal_plate_metal_1k.jpg", ("metallic", None)),
        ("painted_wooden_stool_arm_1k.jpg", ("arm", None)),
        ("Fabric001_COL_VAR1_1K.jpg", ("albedo", None)),  # Poliigon
        ("Fabric001_GLOSS_2K.jpg", ("gloss", None)),
        ("Fabric001_REFL_2K.jpg", ("specular", None)),
        ("Fabric001_NRM16_2K.png", ("normal", None)),
        ("Scratched_gold_01_1K_Base_Color.png", ("albedo", None)),
        ("hardwood2_bump.jpg", ("height", None)),
        ("preview_sphere.png", ("ignored", None)),
        ("holiday.jpg", None),
    ],
)
def test_map_names(name: str, expected: tuple[str, str | None] | None) -> None:
    assert classify_map(name) == expected


def _grey(value: int, size: int = 8) -> np.ndarray:
    return np.full((size, size), value, np.uint8)


def test_gloss_dx_and_unknown_names(tmp_path: Path) -> None:
    folder = tmp_path / "fabric_blue"
    write_png(folder / "blue_COL.png", np.full((8, 8, 3), (10, 20, 200), np.uint8))
    write_png(folder / "blue_GLOSS.png", _grey(200))
    normal = np.zeros((8, 8, 3), np.uint8)
    normal[..., 1] = 40
    write_png(folder / "blue_normal_dx.png", normal)
    write_png(folder / "holiday.png", _grey(1))
    scan = scan_material(folder)
    assert scan.substance == "fabric" and scan.name == "fabric_blue"
    assert any("holiday.png: unrecognised map name" in w for w in scan.warnings)
    maps, meta = load_maps(scan)
    assert (maps["roughness"] == 55).all()  # 1 - gloss
    assert (maps["normal"][..., 1] == 215).all()  # DirectX green flipped to OpenGL
    assert meta["normal_converted_from"] == "dx" and meta["roughness_from"] == "gloss"
    assert maps["albedo"].shape == (8, 8, 3) and maps["roughness"].ndim == 2


def test_arm_unpacking_and_gl_preferred(tmp_path: Path) -> None:
    folder = tmp_path / "wood_x"
    write_png(folder / "x_diff_1k.png", np.full((8, 8, 3), 100, np.uint8))
    write_png(folder / "x_arm_1k.png", np.dstack([_grey(1), _grey(2), _grey(3)]))
    write_png(folder / "x_nor_gl_1k.png", np.full((8, 8, 3), 128, np.uint8))
    write_png(folder / "x_nor_dx_1k.png", np.full((8, 8, 3), 7, np.uint8))
    scan = scan_material(folder)
    maps, _ = load_maps(scan)
    assert (maps["roughness"] == 2).all() and (maps["metallic"] == 3).all()
    assert (maps["normal"] == 128).all()
    assert any("second normal map" in w for w in scan.warnings)


def test_sidecar_json_and_toml(tmp_path: Path) -> None:
    folder = tmp_path / "oak"
    write_png(folder / "weird_name.png", np.full((4, 4, 3), 90, np.uint8))
    (folder / "material.json").write_text(json.dumps({
        "name": "oak_01", "substance": "wood", "scale": 0.5, "license": "CC0-1.0", "attribution": "me",
        "maps": {"albedo": "weird_name.png"}, "normal": "dx",
    }))
    scan = scan_material(folder)
    assert (scan.name, scan.substance, scan.scale, scan.normal_convention) == ("oak_01", "wood", 0.5, "dx")
    assert scan.provenance["license"] == "CC0-1.0"
    analytic = tmp_path / "red_plastic"
    analytic.mkdir()
    (analytic / "material.toml").write_text(
        'name = "red"\nsubstance = "plastic"\nkind = "analytic"\n[params]\nalbedo = [0.8, 0.1, 0.1]\nroughness = 0.3\n'
    )
    scan = scan_material(analytic)
    assert scan.kind == "analytic" and scan.params == {"albedo": [0.8, 0.1, 0.1], "roughness": 0.3}
    assert is_material_folder(analytic) and is_material_folder(folder)


@pytest.mark.parametrize(
    ("sidecar", "reason"),
    [
        ("{not json", "invalid JSON at line 1"),
        ('{"substance": "cheese"}', "unknown substance 'cheese'"),
        ('{"substance": "wood", "scale": -1}', "scale must be a positive number"),
        ('{"substance": "wood", "kind": "analytic", "params": {"albedo": [2, 0, 0]}}', "within 0..1"),
        ('{"substance": "wood", "maps": {"albedo": "../../etc/passwd"}}', "not found in the folder"),
        ('{"substance": "wood"}', "no albedo map"),
        ("[1, 2]", "expected an object"),
    ],
)
def test_bad_sidecars(tmp_path: Path, sidecar: str, reason: str) -> None:
    folder = tmp_path / "m"
    folder.mkdir()
    (folder / "material.json").write_text(sidecar)
    with pytest.raises(BadMaterialError, match=reason):
        scan_material(folder)


def test_substance_is_required(tmp_path: Path) -> None:
    folder = tmp_path / "mystery"
    write_png(folder / "albedo.png", np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(BadMaterialError, match="no substance"):
        scan_material(folder)
    assert scan_material(folder, substance="leather").substance == "leather"


def test_corrupt_map_is_a_material_error(tmp_path: Path) -> None:
    folder = tmp_path / "wood_bad"
    folder.mkdir()
    (folder / "albedo.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(BadMaterialError, match="albedo.png"):
        load_maps(scan_material(folder))


@pytest.mark.realdata
def test_real_material_folders(shared_data: Path) -> None:
    folders = sorted(p for p in (shared_data / "materials").iterdir() if p.is_dir())
    for folder in folders:
        scan = scan_material(folder)
        maps, _ = load_maps(scan)
        assert "albedo" in maps and maps["albedo"].ndim == 3
        assert scan.substance in folder.name
    rosewood = scan_material(shared_data / "materials" / "wood_rosewood_veneer1")
    assert rosewood.conventions["normal"] == "gl" and set(rosewood.files) == {"albedo", "normal", "roughness"}
