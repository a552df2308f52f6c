"""Preprocessing: welding, degenerate faces, unit cube, UVs (source kept, xatlas, box), normals, D_i."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tests.geometry.makers import write_chair_obj

from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.geometry.normals import corner_normals
from photoshape_flow.geometry.obj import parse_obj
from photoshape_flow.geometry.preprocess import PreprocessOptions, preprocess
from photoshape_flow.geometry.primitives import uv_sphere
from photoshape_flow.geometry.raw import BadShapeError, RawMaterial, RawPart, RawShape


def _raw(vertices, faces, uvs=None, name="p") -> RawShape:  # type: ignore[no-untyped-def]
    part = RawPart(name, np.asarray(vertices, float), np.asarray(faces, np.int64),
                   None if uvs is None else np.asarray(uvs, float), RawMaterial(name))
    return RawShape(parts=[part])


def test_unit_cube_contract_and_part_order(tmp_path: Path) -> None:
    mesh = preprocess(parse_obj(write_chair_obj(tmp_path)))
    lo, hi = mesh.bounds()
    assert np.allclose((lo + hi) / 2, 0, atol=1e-6)
    assert (hi - lo).max() == pytest.approx(1.0, abs=1e-6)
    assert [p.index for p in mesh.parts] == [1, 2, 3]
    assert [p.name for p in mesh.parts] == ["legs", "seat", "back"]
    for part in mesh.parts:
        assert part.vertices.dtype == np.float32 and part.faces.dtype == np.int32
        assert len(part.vertices) == len(part.normals) == len(part.uvs)
        assert np.allclose(np.linalg.norm(part.normals, axis=1), 1.0, atol=1e-5)
        assert part.meta["uv_source"] == "xatlas"
        assert part.uv_density == pytest.approx(part.area_uv / part.area_world)
    assert mesh.parts[0].builtin_material["albedo"] == [0.1, 0.1, 0.1]


def test_duplicate_corners_are_welded_and_creases_stay_sharp(tmp_path: Path) -> None:
    # a box written as 6 separate quads: 24 vertices, 8 distinct positions
    from tests.geometry.makers import box_lines

    lines, _ = box_lines((0, 0, 0), (1, 1, 1), 1)
    obj = tmp_path / "box.obj"
    obj.write_text("\n".join(lines) + "\n")
    raw = parse_obj(obj)
    assert len(raw.parts[0].vertices) == 24
    mesh = preprocess(raw, PreprocessOptions(xatlas_max_faces=0))  # box projection keeps it simple
    part = mesh.parts[0]
    assert len(part.faces) == 12
    # every normal is axis-aligned: the 90-degree edges were not smoothed
    assert np.allclose(np.abs(part.normals).max(axis=1), 1.0, atol=1e-5)
    # welding happened: corners of adjacent faces share positions exactly
    assert len(np.unique(part.vertices.round(6), axis=0)) == 8
    assert part.meta["uv_source"] == "box"


def test_smooth_surfaces_get_smooth_normals() -> None:
    sphere = uv_sphere(24, 12).parts[0]
    normals = corner_normals(sphere.vertices, sphere.faces, np.arange(len(sphere.vertices)), 30.0)
    radial = sphere.vertices[sphere.faces] / np.linalg.norm(sphere.vertices[sphere.faces], axis=2, keepdims=True)
    assert np.einsum("ijk,ijk->ij", normals, radial).min() > 0.98


def test_opposite_faces_are_not_averaged() -> None:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 1]])
    normals = corner_normals(vertices, faces, np.arange(3), 30.0)
    assert np.allclose(normals[0], [0, 0, 1]) and np.allclose(normals[1], [0, 0, -1])


def test_degenerate_faces_are_dropped_and_empty_parts_removed() -> None:
    good = _raw([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 2]], [[0, 1, 2], [0, 0, 1], [0, 1, 1]])
    bad = RawPart("flat", np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), np.array([[0, 1, 2]]), None,
                  RawMaterial("flat"))
    good.parts.append(bad)
    mesh = preprocess(good)
    assert [p.name for p in mesh.parts] == ["p"]
    assert len(mesh.parts[0].faces) == 1
    assert mesh.meta["dropped_parts"] == ["flat"]


def test_shapes_with_nothing_left_are_rejected() -> None:
    with pytest.raises(BadShapeError, match="degenerate"):
        preprocess(_raw([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]))
    with pytest.raises(BadShapeError, match="zero-size"):
        preprocess(_raw([[1, 1, 1], [1, 1, 1], [1, 1, 1]], [[0, 1, 2]]))
    with pytest.raises(BadShapeError, match="non-finite"):
        preprocess(_raw([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]], [[0, 1, 2]]))


def test_source_uvs_are_kept_and_density_is_area_ratio() -> None:
    # a 2 x 1 quad with UVs spanning 1 x 0.5: D = A_uv / A_world after scaling into the unit cube
    vertices = [[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]]
    uvs = [[0, 0], [1, 0], [1, 0.5], [0, 0.5]]
    mesh = preprocess(_raw(vertices, [[0, 1, 2], [0, 2, 3]], uvs))
    part = mesh.parts[0]
    assert part.meta["uv_source"] == "source"
    assert part.area_world == pytest.approx(0.5)  # 1 x 0.5 after normalisation
    assert part.area_uv == pytest.approx(0.5)
    assert part.uv_density == pytest.approx(1.0)
    assert sorted(map(tuple, part.uvs.round(3).tolist())) == sorted(map(tuple, np.array(uvs).tolist()))


def test_degenerate_source_uvs_are_regenerated() -> None:
    vertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    mesh = preprocess(_raw(vertices, [[0, 1, 2], [0, 2, 3]], np.zeros((4, 2))))
    assert mesh.parts[0].meta["uv_source"] == "xatlas"
    assert "regenerated" in " ".join(mesh.meta["warnings"])


def test_a_failed_unwrap_falls_back_to_box_uvs(monkeypatch: pytest.MonkeyPatch) -> None:
    """xatlas returned NaN charts for a Sweet Home 3D part (BlendSwap-CC-0, a flower box): the part
    gets box-projected UVs with a warning instead of NaN areas that the database refuses."""
    import photoshape_flow.geometry.preprocess as pre

    real = pre._xatlas_unwrap

    def nan_charts(v, f, options):  # type: ignore[no-untyped-def]
        pos_id, verts, uvs, faces = real(v, f, options)
        return pos_id, verts, np.full_like(uvs, np.nan), faces

    monkeypatch.setattr(pre, "_xatlas_unwrap", nan_charts)
    vertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    part = preprocess(_raw(vertices, [[0, 1, 2], [0, 2, 3]], None)).parts[0]
    assert part.meta["uv_source"] == "box" and np.isfinite(part.uvs).all()
    assert part.area_uv > 0 and np.isfinite(part.uv_density)


def test_uv_seams_survive_welding() -> None:
    # two triangles share an edge in space but not in UV space (a seam): both UV sets must stay
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]
    uvs = [[0, 0], [1, 0], [0, 1], [5, 5], [6, 5], [6, 6]]
    mesh = preprocess(_raw(vertices, [[0, 1, 2], [3, 5, 4]], uvs))
    got = {tuple(uv) for uv in mesh.parts[0].uvs.round(3).tolist()}
    assert {(1.0, 0.0), (5.0, 5.0)} <= got


def test_rotation_is_applied_before_normalising() -> None:
    tall = _raw([[0, 0, 0], [0.1, 0, 0], [0, 0, 1], [0.1, 0, 1]], [[0, 1, 2], [1, 3, 2]])
    mesh = preprocess(tall, PreprocessOptions(rotation=(1, 0, 0, 0, 0, 1, 0, -1, 0)))  # z -> y
    lo, hi = mesh.bounds()
    assert hi[1] - lo[1] == pytest.approx(1.0)


def test_mesh_blob_round_trip(tmp_path: Path) -> None:
    mesh = preprocess(parse_obj(write_chair_obj(tmp_path)))
    data = mesh.to_npz_bytes()
    again = ShapeMesh.from_npz_bytes(data)
    assert [p.name for p in again.parts] == ["legs", "seat", "back"]
    assert np.array_equal(again.parts[1].faces, mesh.parts[1].faces)
    assert again.meta["groups"] == ["Legs", "Seat", "Back"]
    assert preprocess(parse_obj(write_chair_obj(tmp_path))).to_npz_bytes() == data  # deterministic


def test_uv_sphere_faces_point_outwards() -> None:
    part = uv_sphere().parts[0]
    v = part.vertices.astype(np.float64)
    f = part.faces
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    centroids = v[f].mean(axis=1)
    assert (np.einsum("ij,ij->i", normals, centroids) > 0).all()
    assert part.uv_density == pytest.approx(1.0 / np.pi, rel=0.05)  # UV area 1 over area pi


def test_many_unwraps_in_a_row_never_hang() -> None:
    """xatlas can hang in an atlas's destructor (a lost wake-up in its task scheduler); the unwrap
    destroys atlases late so that it cannot. A degenerate part is the quickest atlas, where an
    immediate destruction hung within 2,000-8,000 of them: 30,000 in a row must finish (a child
    process, so that a hang fails the test instead of the suite).

    A hang is a child that stops making progress, not a slow one: the child reports every 500
    unwraps (about a second in the two-worker suite: 69 s for all 30,000) and the test fails only
    after 60 s without a report, so a loaded machine slows the test instead of failing it."""
    import subprocess
    import sys
    import threading

    code = ("import numpy as np\n"
            "from photoshape_flow.geometry.preprocess import PreprocessOptions, _xatlas_unwrap\n"
            "v, f, o = np.zeros((3, 3)), np.array([[0, 1, 2]]), PreprocessOptions()\n"
            "for i in range(1, 30001):\n"
            "    _xatlas_unwrap(v, f, o)\n"
            "    if i % 500 == 0:\n"
            "        print(i, flush=True)\n"
            "print('done', flush=True)\n")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    lines: list[str] = []
    reported = threading.Event()

    def read() -> None:
        assert child.stdout is not None
        for line in child.stdout:
            lines.append(line.strip())
            reported.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        while reader.is_alive():
            if not reported.wait(timeout=60) and reader.is_alive():
                pytest.fail(f"no progress for 60 s after {lines[-1] if lines else 0} of 30,000 xatlas unwraps: "
                            "an atlas's destructor hung")
            reported.clear()
    finally:
        if child.poll() is None:
            child.kill()
        child.wait()
    assert lines[-1:] == ["done"]
    assert child.returncode == 0
