"""Material conversion to metallic-roughness: map formats, packing and constants."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from photoshape_flow.export.pbr import pbr_from_builtin, pbr_from_spec
from photoshape_flow.render import MaterialSpec, srgb_to_linear


def _decode(data: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    return image[..., ::-1] if image.ndim == 3 else image  # BGR -> RGB


def test_sixteen_bit_rgba_and_tiff_maps_become_8bit_rgb(tmp_path):
    rough16 = np.full((4, 6), 32768, np.uint16)  # 0.5
    metal = np.zeros((2, 3), np.uint8)
    metal[0] = 255
    albedo_rgba = np.zeros((4, 6, 4), np.uint8)
    albedo_rgba[..., 0], albedo_rgba[..., 3] = 200, 255
    cv2.imwrite(str(tmp_path / "r.png"), rough16)
    cv2.imwrite(str(tmp_path / "m.png"), metal)
    cv2.imwrite(str(tmp_path / "a.png"), albedo_rgba[..., [2, 1, 0, 3]])
    cv2.imwrite(str(tmp_path / "n.tif"), np.full((4, 4, 3), 40000, np.uint16))
    spec = MaterialSpec("mix", maps={"albedo": tmp_path / "a.png", "roughness": tmp_path / "r.png",
                                     "metallic": tmp_path / "m.png", "normal": tmp_path / "n.tif"})
    pbr = pbr_from_spec(spec)
    base = _decode(pbr.base_color.data)
    assert pbr.base_color.mime == "image/png" and base.shape == (4, 6, 3) and base[0, 0, 0] == 200
    orm = _decode(pbr.orm.data)
    assert orm.shape == (4, 6, 3)  # metallic resized to the larger roughness map
    assert (orm[..., 0] == 255).all() and abs(int(orm[0, 0, 1]) - 128) <= 1
    assert orm[0, 0, 2] == 255 and orm[-1, -1, 2] == 0
    assert (pbr.roughness_factor, pbr.metallic_factor) == (1.0, 1.0)
    assert _decode(pbr.normal.data).dtype == np.uint8 and abs(int(_decode(pbr.normal.data)[0, 0, 0]) - 155) <= 1


def test_png_and_jpeg_albedo_pass_through_unchanged(tmp_path):
    image = np.random.default_rng(0).integers(0, 255, (8, 8, 3), np.uint8)
    for ext in ("png", "jpg"):
        cv2.imwrite(str(tmp_path / f"a.{ext}"), image)
        pbr = pbr_from_spec(MaterialSpec("a", maps={"albedo": tmp_path / f"a.{ext}"}))
        assert pbr.base_color.data == (tmp_path / f"a.{ext}").read_bytes()
    limited = pbr_from_spec(MaterialSpec("a", maps={"albedo": tmp_path / "a.png"}), max_texture_size=4)
    assert _decode(limited.base_color.data).shape == (4, 4, 3)


def test_analytic_and_builtin_constants_are_linear_factors(tmp_path):
    pbr = pbr_from_spec(MaterialSpec("red", params={"albedo": [0.8, 0.1, 0.1], "roughness": 0.35, "metallic": 0.0}))
    assert pbr.base_color is None and pbr.orm is None
    assert pbr.base_color_factor[:3] == pytest.approx(tuple(srgb_to_linear([0.8, 0.1, 0.1])))
    assert (pbr.roughness_factor, pbr.metallic_factor) == (0.35, 0.0)
    texture = tmp_path / "t.png"
    cv2.imwrite(str(texture), np.full((2, 2, 3), 9, np.uint8))
    builtin = {"albedo": [0.5, 0.5, 0.5], "roughness": 0.7, "texture": "abc.png", "name": "skin"}
    with_texture = pbr_from_builtin(builtin, part_name="seat", resolve_ref=lambda ref: texture)
    assert with_texture.builtin and with_texture.base_color is not None and with_texture.base_color_factor[0] == 1.0
    without = pbr_from_builtin(builtin, part_name="seat")  # no resolver: the constant colour only
    assert without.base_color is None and without.name == "skin"
