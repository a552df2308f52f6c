"""OBJ+MTL export: reloads with trimesh into one textured group per part."""

from __future__ import annotations

import numpy as np
import trimesh

from photoshape_flow.export.obj import write_obj
from photoshape_flow.render.specs import UVTransform, apply_uv_matrix, uv_matrix


def test_obj_reloads_with_one_group_per_part(tmp_path, tiny_shape, tiny_materials):
    jitter = UVTransform(scale=0.5, rotation=1.0, offset=(0.3, 0.0))
    files = write_obj(tmp_path / "o" / "chair.obj", tiny_shape, tiny_materials, [jitter, None],
                      header=["oak_01: CC0-1.0 (demo)"])
    names = {f.relative_to(tmp_path / "o").as_posix() for f in files}
    assert {"chair.obj", "chair.mtl", "textures/oak_01_basecolor.png", "textures/oak_01_normal.png",
            "textures/steel_02_metallic.png"} <= names
    assert "textures/oak_01_metallic.png" not in names  # oak has no metallic map: Pm only
    mtl = (tmp_path / "o" / "chair.mtl").read_text()
    assert "# oak_01: CC0-1.0 (demo)" in mtl and "norm textures/oak_01_normal.png" in mtl

    scene = trimesh.load(tmp_path / "o" / "chair.obj", force="scene", split_objects=True, group_material=False)
    assert sorted(scene.geometry) == ["leg", "seat"]
    for part, material in zip(tiny_shape.parts, ("oak_01", "steel_02"), strict=True):
        mesh = scene.geometry[part.name]
        assert len(mesh.faces) == len(part.faces)
        assert mesh.visual.material.name == material
        assert mesh.visual.material.image is not None and mesh.visual.material.image.size[0] > 0
        np.testing.assert_allclose(np.sort(mesh.vertices, axis=0), np.sort(part.vertices, axis=0), atol=1e-6)
    seat = tiny_shape.parts[0]
    expected = apply_uv_matrix(seat.uvs, uv_matrix(seat.uv_density, 0.25, jitter))
    got = scene.geometry["seat"].visual.uv
    # trimesh may reorder vertices: compare the sets of UV rows
    np.testing.assert_allclose(np.sort(got, axis=0), np.sort(expected, axis=0), atol=1e-5)


def test_obj_builtin_material_keeps_constant_colour(tmp_path, tiny_shape):
    write_obj(tmp_path / "b.obj", tiny_shape, [None, None])
    mtl = (tmp_path / "b.mtl").read_text()
    assert "newmtl chrome" in mtl and "Pm 1.000000" in mtl and "map_Kd" not in mtl


def test_obj_carries_a_refinement_as_kd_and_baked_texcoords(tmp_path, tiny_shape, tiny_materials):
    from dataclasses import replace

    from photoshape_flow.render.specs import Refinement, refined_uv_matrix

    refined = replace(tiny_materials[0], refinement=Refinement((0.8, 0.5, 0.4), 1.0, 1.4, 0.7))
    write_obj(tmp_path / "r.obj", tiny_shape, [refined, tiny_materials[1]])
    assert "Kd 0.800000 0.500000 0.400000" in (tmp_path / "r.mtl").read_text()  # multiplies map_Kd
    seat = tiny_shape.parts[0]
    expected = apply_uv_matrix(seat.uvs, refined_uv_matrix(seat.uv_density, refined))
    scene = trimesh.load(tmp_path / "r.obj", force="scene", split_objects=True, group_material=False)
    np.testing.assert_allclose(np.sort(scene.geometry["seat"].visual.uv, axis=0), np.sort(expected, axis=0),
                               atol=1e-5)
    assert not np.allclose(expected, apply_uv_matrix(seat.uvs, uv_matrix(seat.uv_density, 0.25)))
