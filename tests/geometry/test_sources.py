"""Discovery of shape sources, safe archive handling, Sweet Home 3D catalogs, content hashes."""

from __future__ import annotations

import stat
import zipfile
from pathlib import Path

import pytest
from tests.geometry.makers import chair_members, write_chair_obj, write_sh3f, write_shapenet_tree

from photoshape_flow.geometry.archive import SafeZip, UnsafeArchiveError, normalise_member
from photoshape_flow.geometry.prepare import prepare_shape
from photoshape_flow.geometry.preprocess import PreprocessOptions
from photoshape_flow.geometry.raw import BadShapeError
from photoshape_flow.geometry.sh3f import category_of, parse_properties
from photoshape_flow.geometry.sources import RejectedInput, ShapeItem, discover_shapes, materialize

CHAIR = {"id": "Test#chair", "name": "Caf\\u00e9 chair", "category": "Living room", "tags": "Seat",
         "model": "/test/chair/chair.obj", "creator": "Someone", "width": "50", "depth": "50", "height": "90",
         "modelRotation": "1 0 0 0 0 1 0 -1 0"}
TABLE = {"id": "Test#table", "name": "Table", "category": "Kitchen", "tags": "", "model": "/test/table/chair.obj"}


def test_properties_parser_handles_escapes_and_continuations() -> None:
    props = parse_properties("# c\nname=Caf\\u00e9\nlong=a \\\n  b\nkey\\=x : value\n! bang\nspace value\n")
    assert props["name"] == "Café"
    assert props["long"] == "a b"
    assert props["key=x"] == "value"
    assert props["space"] == "value"


def test_category_keywords() -> None:
    assert category_of("Armchair") == "chair"
    assert category_of("Futon couch") == "sofa"
    assert category_of("Bar stool", "Seat") == "stool"
    assert category_of("Lamp post", "", "Exterior") == "lamp"
    assert category_of("Fridge", "", "Kitchen") == "kitchen"


def test_plain_files_and_shapenet_layout(tmp_path: Path) -> None:
    write_chair_obj(tmp_path / "plain")
    write_shapenet_tree(tmp_path / "ShapeNetCore.v2", "03001627", "m1")
    (tmp_path / "plain" / "notes.txt").write_text("ignored")
    items = discover_shapes([tmp_path], category="chair")
    by_source = {(i.source, i.source_id): i for i in items if isinstance(i, ShapeItem)}
    # plain files: the path relative to the folder given; ShapeNet keeps synset/model
    assert set(by_source) == {("local", "plain/chair"), ("shapenet", "03001627/m1")}
    assert by_source[("shapenet", "03001627/m1")].category == "chair"
    assert by_source[("local", "plain/chair")].category == "chair"
    assert by_source[("local", "plain/chair")].legacy_id == "chair"
    # a file given by itself keeps its stem
    (alone,) = discover_shapes([tmp_path / "plain" / "chair.obj"])
    assert isinstance(alone, ShapeItem) and alone.source_id == "chair"
    # ShapeNet category filter
    assert all(i.source != "shapenet" for i in discover_shapes([tmp_path], category="sofa")
               if isinstance(i, ShapeItem))


def test_bad_paths_are_rejected_inputs(tmp_path: Path) -> None:
    fbx = tmp_path / "x.fbx"
    fbx.write_text("x")
    items = discover_shapes([tmp_path / "missing.obj", fbx])
    assert all(isinstance(i, RejectedInput) for i in items)
    assert "no such file" in items[0].reason and "unsupported file type '.fbx'" in items[1].reason
    with pytest.raises(ValueError, match="invalid --name-filter"):
        discover_shapes([tmp_path], name_filter="(")


def test_sh3f_catalog_items_filters_and_rotation(tmp_path: Path) -> None:
    members = {**chair_members("test/chair"), **chair_members("test/table")}
    catalog = write_sh3f(tmp_path / "cat.sh3f", [CHAIR, TABLE], members)
    items = discover_shapes([catalog])
    assert [i.source_id for i in items] == ["cat/Test#chair", "cat/Test#table"]
    chair = items[0]
    assert isinstance(chair, ShapeItem)
    assert chair.name == "Café chair" and chair.category == "chair" and chair.source == "sweethome3d"
    assert chair.rotation == (1, 0, 0, 0, 0, 1, 0, -1, 0)
    assert chair.license == "CC0" and "Someone" in (chair.attribution or "")
    assert [i.source_id for i in discover_shapes([catalog], category="chair")] == ["cat/Test#chair"]
    assert [i.source_id for i in discover_shapes([catalog], name_filter="^tab")] == ["cat/Test#table"]
    with materialize(chair) as files:
        assert files.model.is_file() and files.model.name == "chair.obj"
        assert sorted(files.files) == ["test/chair/chair.mtl", "test/chair/chair.obj"]
        prepared = prepare_shape(str(files.model), "obj", str(files.root), PreprocessOptions(rotation=chair.rotation))
        extracted_root = files.root
    assert [p.name for p in prepared.mesh.parts] == ["legs", "seat", "back"]
    assert not extracted_root.exists()  # temporary extraction is cleaned up


def test_content_hash_tracks_mtl_and_textures(tmp_path: Path) -> None:
    obj = write_chair_obj(tmp_path / "a", with_texture=True)
    item = next(i for i in discover_shapes([obj]) if isinstance(i, ShapeItem))
    with materialize(item) as files:
        first = files.sha256
    with materialize(item) as files:
        assert files.sha256 == first
    mtl = tmp_path / "a" / "chair.mtl"
    mtl.write_text(mtl.read_text().replace("0.1 0.1 0.1", "0.2 0.2 0.2"))
    with materialize(item) as files:
        second = files.sha256
    assert second != first
    import numpy as np
    from tests.geometry.makers import write_png

    write_png(tmp_path / "a" / "tex" / "seat.png", np.zeros((8, 8, 3), np.uint8))
    with materialize(item) as files:
        assert files.sha256 != second


@pytest.mark.parametrize("name", ["../evil.obj", "/abs/evil.obj", "C:/evil.obj", "a/../../evil.obj"])
def test_unsafe_member_names(name: str) -> None:
    with pytest.raises(UnsafeArchiveError):
        normalise_member(name)


def test_path_traversal_in_model_path_and_mtllib(tmp_path: Path) -> None:
    evil = dict(CHAIR, id="Test#evil", model="/../../etc/evil.obj")
    members = chair_members("test/chair")
    members["test/chair/chair.obj"] = members["test/chair/chair.obj"].replace(b"mtllib chair.mtl",
                                                                              b"mtllib ../../../../etc/passwd")
    catalog = write_sh3f(tmp_path / "cat.sh3f", [evil, CHAIR], members)
    items = discover_shapes([catalog])
    assert isinstance(items[0], RejectedInput) and "traversal" in items[0].reason
    chair = items[1]
    assert isinstance(chair, ShapeItem)
    with pytest.raises(UnsafeArchiveError, match="traversal"), materialize(chair):
        pass


def test_symlink_and_bomb_members_are_refused(tmp_path: Path) -> None:
    link = zipfile.ZipInfo("test/chair/link.obj")
    link.external_attr = (stat.S_IFLNK | 0o777) << 16
    big = zipfile.ZipInfo("test/chair/big.obj")
    big.compress_type = zipfile.ZIP_DEFLATED
    catalog = write_sh3f(tmp_path / "cat.sh3f", [], {}, extra=[(link, b"/etc/passwd"), (big, b"v 0 0 0\n" * 2_000_000)])
    with SafeZip(catalog) as archive:
        with pytest.raises(UnsafeArchiveError, match="symbolic link"):
            archive.read("test/chair/link.obj")
        with pytest.raises(UnsafeArchiveError, match="decompression bomb"):
            archive.read("test/chair/big.obj")


def test_not_a_zip(tmp_path: Path) -> None:
    path = tmp_path / "fake.sh3f"
    path.write_bytes(b"PK\x03\x04 not really")
    items = discover_shapes([path])
    assert isinstance(items[0], RejectedInput) and "zip" in items[0].reason
    no_catalog = write_sh3f(tmp_path / "x.sh3f", [], {})
    with zipfile.ZipFile(no_catalog, "w") as zf:
        zf.writestr("readme.txt", "hello")
    items = discover_shapes([no_catalog])
    assert isinstance(items[0], RejectedInput) and "PluginFurnitureCatalog" in items[0].reason


def test_missing_model_member_is_a_bad_shape(tmp_path: Path) -> None:
    catalog = write_sh3f(tmp_path / "cat.sh3f", [CHAIR], {})
    chair = discover_shapes([catalog])[0]
    assert isinstance(chair, ShapeItem)
    with pytest.raises(BadShapeError, match="missing"), materialize(chair):
        pass
