"""Hostile input through `photoshape ingest`: 76 kinds, each one clear line and 0 tracebacks, and the batch goes on.

Each case writes one tiny hostile input (sidecars nested 400 KB deep or 2 MB large, folders named like
files, non-zip and zip-bomb catalogs, names with a newline, a right-to-left override, HTML or rich
markup, empty and truncated PNG/JPEG/HDR/EXR/GLB, symlinks out of the folder, ...) beside one good
input of the same collection, and runs the real CLI (`photoshape ingest <collection>`). Every case
must: exit 0 (accepted) or 2 (rejected, never a crash), print no traceback and no control or bidi
character, name the hostile file on a `rejected` line with the expected reason, and still ingest
the good input after it. The count (76 kinds) is asserted below so it cannot shrink unnoticed.
`POISON` adds sidecars and catalog properties whose values parse but cannot be stored or used, each
run twice beside good inputs: one line, every good input in, nothing rewritten by the second run.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import re
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import sqlalchemy as sa
from tests.geometry.makers import chair_members, write_chair_obj, write_png, write_sh3f
from tests.imaging.test_exemplar import photo
from tests.imaging.test_hdr import sky, write_hdr
from tests.imaging.test_io import png_declaring
from typer.testing import CliRunner

from photoshape_flow.cli import app
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope

runner = CliRunner()
FORBIDDEN = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")
TABLES = {"shapes": m.Shape, "exemplars": m.Exemplar, "materials": m.Material, "envmaps": m.Envmap}
NESTED = 200_000  # 400 KB of brackets: deeper than Python's parsers can recurse
CHAIR = {"id": "T#chair", "name": "Chair", "category": "Living room", "tags": "", "creator": "X",
         "model": "/t/chair/chair.obj"}


def _file(relative: str, data: bytes | str) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data.encode() if isinstance(data, str) else data)
        return root

    return build


def _sidecar(text: str | bytes, name: str = "material.json", maps: bool = True) -> Callable[[Path], Path]:
    """A material folder `a_bad` (sorted before the good one) with this sidecar and an albedo map."""
    def build(root: Path) -> Path:
        _file(f"a_bad/{name}", text)(root)
        if maps:
            write_png(root / "a_bad" / "albedo.png", np.zeros((4, 4, 3), np.uint8))
        return root

    return build


def _json(**fields: object) -> str:
    return json.dumps({"substance": "wood", **fields})


def _folder(relative: str) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        (root / relative).mkdir(parents=True)
        return root

    return build


def _given(relative: str, build: Callable[[Path], Path] | None = None) -> Callable[[Path], Path]:
    """The hostile path is given on the command line itself (not found inside a folder)."""
    def run(root: Path) -> Path:
        if build is not None:
            build(root)
        return root / relative

    return run


def _symlink(relative: str, target: Callable[[Path], Path]) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        (root / relative).parent.mkdir(parents=True, exist_ok=True)
        os.symlink(target(root), root / relative)
        return root

    return build


def _outside(root: Path) -> Path:
    secret = root.parent / "outside" / "secret.obj"
    secret.parent.mkdir(parents=True, exist_ok=True)
    write_chair_obj(secret.parent, "secret")
    return secret


def _png_bytes(array: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, "PNG")
    return buffer.getvalue()


def _chair_obj(name: str) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        write_chair_obj(root, name)
        return root

    return build


def _sh3f(members: dict[str, bytes], extra: list[tuple[zipfile.ZipInfo, bytes]] | None = None,
          entries: list[dict[str, str]] | None = None) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        write_sh3f(root / "a_cat.sh3f", entries if entries is not None else [CHAIR], members, extra)
        return root

    return build


def _zip_without_catalog(root: Path) -> Path:
    with zipfile.ZipFile(root / "a_cat.sh3f", "w") as zf:
        zf.writestr("readme.txt", "no catalog")
    return root


def _bomb_member() -> tuple[dict[str, bytes], list[tuple[zipfile.ZipInfo, bytes]]]:
    """A catalog whose model is 4 MiB of spaces deflated to a few KB (ratio far above the limit)."""
    members = chair_members("t/chair")
    members["t/chair/chair.obj"] = members["t/chair/chair.obj"] + b" " * (4 * 1024 * 1024)
    return members, []


def _outside_file(root: Path, name: str) -> Path:
    """A valid file of that kind beside the ingested folder, not inside it."""
    target = root.parent / "outside" / name
    target.parent.mkdir(parents=True, exist_ok=True)
    if name.endswith(".hdr"):
        write_hdr(target, sky(16, 8))
    else:
        target.write_bytes(PNG if name.endswith(".png") else b'{"substance": "wood"}')
    return target


def _outside_png(root: Path) -> Path:
    return _outside_file(root, "other.png")


def _outside_material(root: Path) -> Path:
    folder = root.parent / "outside" / "wood_elsewhere"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "albedo.png").write_bytes(PNG)
    return folder


def _material_link(name: str, target: Callable[[Path], Path]) -> Callable[[Path], Path]:
    """Material folder `wood_a` whose `name` is a symbolic link to `target` (plus a real albedo otherwise)."""
    def build(root: Path) -> Path:
        folder = root / "wood_a"
        folder.mkdir(parents=True, exist_ok=True)
        if name != "albedo.png":
            (folder / "albedo.png").write_bytes(PNG)
        os.symlink(target(root), folder / name)
        return root

    return build


def _envmap(values: np.ndarray) -> Callable[[Path], Path]:
    def build(root: Path) -> Path:
        write_hdr(root / "a.hdr", values)
        return root

    return build


def _absurd_sky() -> np.ndarray:
    values = sky(16, 8)
    values[2, 3] = 1.7e38  # RGBE encodes it; its luminance overflows float32
    return values


PNG = _png_bytes(np.full((8, 8, 3), 200, np.uint8))
TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
HDR_TEXT = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 512 +X 1024\n" + b"\x02\x02\x04\x00" * 8
CASES: list[tuple[str, str, Callable[[Path], Path], str | None]] = [
    # (id, collection, build(root) -> path given, expected reason fragment or None when accepted)
    # --- material sidecars
    ("json-nested-brackets", "materials", _sidecar("[" * NESTED + "]" * NESTED), "nested 200000 levels deep"),
    ("json-nested-objects", "materials", _sidecar('{"a":' * 50 + "1" + "}" * 50), "nested 50 levels deep"),
    ("toml-nested-brackets", "materials", _sidecar("a = " + "[" * NESTED + "]" * NESTED, "material.toml"),
     "nested 200000 levels deep"),
    ("toml-nested-inline-tables", "materials", _sidecar("a = " + "{b = " * 40 + "1" + "}" * 40, "material.toml"),
     "nested 40 levels deep"),
    ("json-huge", "materials", _sidecar('{"pad": "' + "x" * 2_000_000 + '"}'), "bytes (limit 1048576)"),
    ("json-invalid", "materials", _sidecar('{"substance": "wood",'), "invalid JSON"),
    ("json-not-object", "materials", _sidecar("[1, 2]"), "expected an object"),
    ("json-not-utf8", "materials", _sidecar(b'{"name": "\xff\xfe"}'), "not UTF-8"),
    ("json-empty", "materials", _sidecar(""), "invalid JSON"),
    ("toml-invalid", "materials", _sidecar("a = = 1", "material.toml"), "invalid TOML"),
    ("json-name-newline", "materials", _sidecar(_json(name="oak\nmtllib /etc/passwd")), "U+000A"),
    ("json-name-rtl-override", "materials", _sidecar(_json(name="oak\u202egnp.exe")), "U+202E"),
    ("json-name-nul", "materials", _sidecar(_json(name="oak\u0000")), "U+0000"),
    ("json-name-isolate", "materials", _sidecar(_json(name="oak\u2066x\u2069")), "U+2066"),
    ("json-attribution-list", "materials", _sidecar(_json(attribution=["a", "b"])), "attribution must be text"),
    ("json-source-too-long", "materials", _sidecar(_json(source="s" * 65)), "source is 65 characters"),
    ("json-scale-nan", "materials", _sidecar('{"substance": "wood", "scale": NaN}'), "non-finite number NaN"),
    ("json-params-string", "materials", _sidecar(_json(kind="analytic", params="x"), maps=False), "params must be"),
    ("json-html-attribution", "materials", _sidecar(_json(attribution="<script>alert(1)</script>\nline 2")), None),
    ("material-map-empty", "materials", _file("wood_a/albedo.png", b""), "albedo"),
    ("material-map-truncated", "materials", _file("wood_a/albedo.png", PNG[:40]), "albedo"),
    ("material-folder-newline", "materials", _file("wood_a\nb/albedo.png", PNG), "U+000A"),
    ("json-scale-5000-digits", "materials", _sidecar('{"substance": "wood", "scale": ' + "1" * 5000 + "}"),
     "a number with 5000 digits (limit 24)"),
    ("toml-scale-5000-digits", "materials", _sidecar('substance = "wood"\nscale = ' + "1" * 5000, "material.toml"),
     "more than 4300 digits"),
    ("toml-scale-100-digits", "materials", _sidecar('substance = "wood"\nscale = ' + "1" * 100, "material.toml"),
     "beyond the limit"),
    ("json-scale-overflowing-float", "materials", _sidecar('{"substance": "wood", "scale": 1e400}'),
     "non-finite number inf"),
    ("json-params-absurd-float", "materials", _sidecar('{"substance": "wood", "params": {"x": 1e300}}'),
     "beyond the limit"),
    ("material-map-symlink-outside", "materials", _material_link("albedo.png", _outside_png),
     "albedo.png: symbolic link to"),
    ("material-map-symlink-passwd", "materials", _material_link("albedo.png", lambda _root: Path("/etc/passwd")),
     "outside the ingested folder"),
    ("material-extra-map-symlink-outside", "materials", _material_link("rough.png", _outside_png),
     "rough.png: symbolic link to"),
    ("material-sidecar-symlink-outside", "materials",
     _material_link("material.json", lambda root: _outside_file(root, "m.json")), "material.json: symbolic link to"),
    ("material-folder-symlink-outside", "materials", _symlink("wood_link", _outside_material),
     "outside the ingested folder"),
    ("material-given-file", "materials", _given("x.png", _file("x.png", PNG)), "expected a material folder"),
    # --- shapes
    ("dir-named-obj-inside", "shapes", _folder("folder.obj"), "a folder, not a file"),
    ("dir-named-obj-given", "shapes", _given("folder.obj", _folder("folder.obj")), "no .glb .gltf .obj .sh3f files"),
    ("sh3f-not-zip", "shapes", _file("a_cat.sh3f", "not a zip"), "a_cat.sh3f"),
    ("sh3f-no-catalog", "shapes", _zip_without_catalog, "a_cat.sh3f"),
    ("sh3f-zip-bomb-entry", "shapes", _sh3f(*_bomb_member()), "decompression bomb"),
    ("sh3f-traversal-entry", "shapes",
     _sh3f(chair_members("t/chair"), entries=[{**CHAIR, "model": "/../../etc/chair.obj"}]), "a_cat.sh3f:T#chair"),
    ("sh3f-id-newline", "shapes", _sh3f(chair_members("t/chair"), entries=[{**CHAIR, "id": "T#ch\\nair"}]),
     "catalog id contains U+000A"),
    ("sh3f-empty", "shapes", _file("a_cat.sh3f", b""), "a_cat.sh3f"),
    ("name-newline", "shapes", _chair_obj("a\nmtllib evil"), "U+000A"),
    ("name-rtl-override", "shapes", _chair_obj("a\u202ejbo.exe"), "U+202E"),
    ("name-escape-sequence", "shapes", _chair_obj("a\x1b[31m"), "U+001B"),
    ("name-html-and-markup", "shapes", _file("<b>[/red]x</b>.obj", "v 0 0 0\n"), "<b>[/red]x</b>.obj"),
    ("name-html-valid", "shapes", _chair_obj("<img src=x onerror=alert(1)>"), None),
    ("obj-empty", "shapes", _file("a.obj", b""), "a.obj"),
    ("obj-binary-nul", "shapes", _file("a.obj", b"\x00\xff" * 500), "a.obj"),
    ("obj-bad-index", "shapes", _file("a.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999\n"), "a.obj"),
    ("obj-mtllib-outside", "shapes",
     _file("a.obj", "mtllib ../../../../etc/passwd\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), None),
    ("obj-coordinates-1e308", "shapes", _file("a.obj", "v 1e308 0 0\nv -1e308 0 0\nv 0 1e308 0\nf 1 2 3\n"),
     "vertex coordinates beyond 1e+12"),
    ("obj-part-name-rtl-override", "shapes", _file("a.obj", "usemtl oak\u202egnp.exe\n" + TRIANGLE + "f 1 2 3\n"),
     "part name"),
    ("obj-part-name-escape-sequence", "shapes", _file("a.obj", "usemtl x\x1b[31m\n" + TRIANGLE + "f 1 2 3\n"),
     "U+001B"),
    ("glb-empty", "shapes", _file("a.glb", b""), "a.glb"),
    ("glb-truncated", "shapes", _file("a.glb", b"glTF\x02\x00\x00\x00\xff\xff"), "a.glb"),
    ("gltf-nested-json", "shapes", _file("a.gltf", "[" * NESTED + "]" * NESTED), "a.gltf"),
    ("symlink-outside-root", "shapes", _symlink("a.obj", _outside), "outside the ingested folder"),
    ("symlink-broken", "shapes", _symlink("a.obj", lambda root: root / "missing.obj"), "broken symbolic link"),
    ("path-missing", "shapes", _given("missing.obj"), "no such file or folder"),
    ("file-unsupported", "shapes", _given("a.fbx", _file("a.fbx", "x")), "unsupported file type '.fbx'"),
    # --- exemplars
    ("jpg-empty", "exemplars", _file("a.jpg", b""), "a.jpg"),
    ("png-truncated", "exemplars", _file("a.png", PNG[: len(PNG) // 2]), "a.png"),
    ("png-is-text", "exemplars", _file("a.png", "hello"), "a.png"),
    ("png-decompression-bomb", "exemplars", _file("a.png", png_declaring(50_000, 50_000)), "a.png"),
    ("png-strip-80000x2", "exemplars", _file("a.png", _png_bytes(np.zeros((2, 80000), np.uint8))),
     "aspect ratio 40000:1"),
    ("png-strip-2x30000", "exemplars", _file("a.png", _png_bytes(np.zeros((30000, 2), np.uint8))),
     "aspect ratio 15000:1"),
    ("photo-symlink-outside", "exemplars", _symlink("a.png", _outside_png), "outside the ingested folder"),
    ("photo-name-rtl-override", "exemplars", _file("a\u202egnp.jpg", PNG), "U+202E"),
    ("dir-named-jpg", "exemplars", _folder("a.jpg"), "a folder, not a file"),
    # --- envmaps
    ("hdr-truncated", "envmaps", _file("a.hdr", HDR_TEXT), "a.hdr"),
    ("hdr-empty", "envmaps", _file("a.hdr", b""), "a.hdr"),
    ("exr-garbage", "envmaps", _file("a.exr", b"v/1\x01" + b"\x00" * 64), "a.exr"),
    ("hdr-radiance-1.7e38", "envmaps", _envmap(_absurd_sky()), "radiance up to 1.69e+38, beyond the limit"),
    ("hdr-nan", "envmaps", _envmap(np.full((8, 16, 3), np.nan, np.float32)), "a.hdr"),
    ("hdr-symlink-outside", "envmaps", _symlink("a.hdr", lambda root: _outside_file(root, "a.hdr")),
     "outside the ingested folder"),
    ("dir-named-hdr", "envmaps", _folder("a.hdr"), "a folder, not a file"),
]
KINDS = 76  # the docstring's count


@pytest.fixture(scope="module")
def migrated_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One migrated SQLite file for the module: each case starts from a copy (migrating 60 times costs ~8 s)."""
    from photoshape_flow.db import migrate

    path = tmp_path_factory.mktemp("hostile-template") / "photoshape.db"
    migrate.upgrade(f"sqlite:///{path}")
    return path


@pytest.fixture
def db_url(settings_env: Path, migrated_template: Path) -> str:
    """The conftest fixture's migrated database under the test's data root, copied from the template."""
    from photoshape_flow.config import get_settings

    url = get_settings().resolved_database_url
    target = Path(url.removeprefix("sqlite:///"))
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(migrated_template, target)
    return url


def _good(collection: str, root: Path) -> Path:
    """One valid input of the collection, in a folder that sorts after the hostile one."""
    folder = root / "zz_good"
    if collection == "shapes":
        write_chair_obj(folder, "good")
    elif collection == "exemplars":
        write_png(folder / "good.png", photo(width=96, height=64, box=(30, 10, 60, 50)))
    elif collection == "materials":
        write_png(folder / "wood_good" / "albedo.png", np.full((4, 4, 3), 120, np.uint8))
    else:
        folder.mkdir(parents=True)
        write_hdr(folder / "good.hdr", sky(16, 8))
    return folder


def _ok_rows(url: str, collection: str) -> int:
    model = TABLES[collection]
    with session_scope(url) as session:
        return session.execute(sa.select(sa.func.count()).select_from(model).where(model.status == "ok")).scalar_one()


def test_the_case_count_matches_the_docstring() -> None:
    assert len(CASES) >= KINDS >= 40 and len({case[0] for case in CASES}) == len(CASES)


@pytest.mark.parametrize(("collection", "build", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_hostile_input_is_one_clear_line_and_the_batch_goes_on(
    db_url: str, tmp_path: Path, collection: str, build: Callable[[Path], Path], expected: str | None,
) -> None:
    root = tmp_path / "in"
    root.mkdir()
    given = build(root)
    good = _good(collection, tmp_path)
    extra = ["--no-isolate"] if collection == "shapes" else ["--no-previews"] if collection == "materials" else []
    result = runner.invoke(app, ["ingest", collection, str(given), str(good), *extra])
    output = result.output
    assert "Traceback" not in output and "RecursionError" not in output, output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert not FORBIDDEN.search(output), (FORBIDDEN.search(output), output)
    flat = "".join(output.split())
    if expected is None:
        assert result.exit_code == 0, output
    else:
        assert result.exit_code == 2, output
        rejected = [line for line in output.splitlines() if line.startswith("rejected")]
        assert rejected and "".join(expected.split()) in flat, output
    assert _ok_rows(db_url, collection) >= 1 + (expected is None), output  # the good input after it went in


def test_rejected_rows_keep_no_hidden_characters(db_url: str, tmp_path: Path) -> None:
    write_png(tmp_path / "wood_a\u202eb\nc" / "albedo.png", np.zeros((4, 4, 3), np.uint8))
    result = runner.invoke(app, ["ingest", "materials", str(tmp_path), "--no-previews"])
    assert result.exit_code == 2 and "U+000A" in "".join(result.output.split()), result.output
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Material)).scalar_one()
        assert row.status == "rejected" and not FORBIDDEN.search(row.name + row.error), (row.name, row.error)


def test_a_rejected_catalog_gets_a_rejected_row(db_url: str, tmp_path: Path) -> None:
    (tmp_path / "broken.sh3f").write_text("not a zip")
    result = runner.invoke(app, ["ingest", "shapes", str(tmp_path / "broken.sh3f"), "--no-isolate"])
    assert result.exit_code == 2, result.output
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Shape)).scalar_one()
        assert (row.source, row.source_id, row.status) == ("sweethome3d", "broken", "rejected") and row.error


# --- poison sidecars and catalog properties: values that parse but cannot be stored or used ------------
# Each hostile item sorts before its good neighbours, which must all go in; it costs exactly one
# `rejected` line naming it, and a second run changes nothing (the writes are idempotent). A catalog
# piece's unstorable id must not reach a row's write outside the item guard, where it ends the batch.
S = "\\ud800"  # a .properties escape for a lone surrogate
POISON: list[tuple[str, str, Callable[[Path], Path], str, str]] = [
    # (id, collection, build(root) -> path given, the rejected line's item, expected reason fragment)
    ("json-license-lone-surrogate", "materials", _sidecar('{"substance": "wood", "license": "\\ud800"}'),
     "a_bad", "material.json: text '\\ud800' contains U+D800 (a lone surrogate, which cannot be stored)"),
    ("json-params-nul", "materials", _sidecar('{"substance": "wood", "params": {"x": "a\\u0000b"}}'),
     "a_bad", "contains U+0000 (null, which cannot be stored)"),
    ("toml-params-datetime", "materials", _sidecar('substance = "wood"\n[params]\nwhen = 1979-05-27T07:32:00\n',
                                                   "material.toml"), "a_bad", "material.toml: a datetime value"),
    ("json-scale-true", "materials", _sidecar(_json(scale=True)), "a_bad", "scale must be a number, got True"),
    ("json-scale-string", "materials", _sidecar(_json(scale="1e300")), "a_bad", "scale must be a number, got '1e300'"),
    ("json-scale-denormal", "materials", _sidecar(_json(scale=5e-324)), "a_bad", "scale must be within 1e-06..1e+06"),
    ("json-roughness-string", "materials", _sidecar(_json(params={"roughness": "0.5"})), "a_bad",
     "params.roughness must be a number, got '0.5'"),
    ("sh3f-rejected-piece-id-lone-surrogate", "shapes", _sh3f(chair_members("t/chair"), entries=[
        CHAIR, {**CHAIR, "id": f"T#x{S}", "model": ""}]), "a_cat.sh3f:T#x\\ud800",
     "catalog id contains U+D800 (a lone surrogate, which cannot be stored)"),
    ("sh3f-unsupported-piece-name-lone-surrogate", "shapes", _sh3f(chair_members("t/chair"), entries=[
        CHAIR, {**CHAIR, "id": "T#fbx", "name": f"x{S}", "model": "/t/chair/chair.fbx"}]), "a_cat.sh3f:T#fbx",
     "name contains U+D800"),
    ("sh3f-creator-lone-surrogate", "shapes", _sh3f(chair_members("t/chair"), entries=[
        CHAIR, {**CHAIR, "id": "T#c2", "creator": S}]), "a_cat.sh3f:T#c2", "creator contains U+D800"),
    ("sh3f-name-past-its-column", "shapes", _sh3f(chair_members("t/chair"), entries=[
        CHAIR, {**CHAIR, "id": "T#c2", "name": "n" * 256}]), "a_cat.sh3f:T#c2", "name is 256 characters long"),
]


def _rows(url: str, collection: str) -> dict[str, dict[str, object]]:
    """Every row of the collection's table by key, all columns (timestamps too: a rewrite shows)."""
    model = TABLES[collection]
    with session_scope(url) as session:
        rows = [dict(r._mapping) for r in session.execute(sa.select(model.__table__))]
    return {str(r["name"] if collection == "materials" else r["source_id"]): r for r in rows}


@pytest.mark.parametrize(("collection", "build", "item", "expected"), [c[1:] for c in POISON],
                         ids=[c[0] for c in POISON])
def test_a_poison_sidecar_is_one_line_and_the_rest_of_the_batch_goes_in(
    db_url: str, tmp_path: Path, collection: str, build: Callable[[Path], Path], item: str, expected: str,
) -> None:
    root = tmp_path / "in"
    root.mkdir()
    given = build(root)
    if collection == "materials":
        write_png(root / "0_good" / "albedo.png", np.full((4, 4, 3), 90, np.uint8))
        (root / "0_good" / "material.json").write_text(_json(name="oak_sidecar"))
        goods, extra = {"oak_sidecar", "wood_good"}, ["--no-previews"]
    else:
        goods, extra = {"a_cat/T#chair", "good"}, ["--no-isolate"]
    good = _good(collection, tmp_path)
    stored: dict[str, dict[str, object]] = {}
    for attempt in ("first", "again"):
        result = runner.invoke(app, ["ingest", collection, str(given), str(good), *extra])
        output = result.output
        assert "Traceback" not in output and result.exit_code == 2, (attempt, output)
        assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
        assert not FORBIDDEN.search(output), (FORBIDDEN.search(output), output)
        lines = output.splitlines()
        starts = [i for i, line in enumerate(lines) if line.startswith("rejected")]
        assert len(starts) == 1, (attempt, output)
        # the entry as printed, wherever the console wrapped its long path: up to the next entry or the total
        rest = itertools.takewhile(lambda line: not re.match(r"(ok|rejected) |\d+ of \d+ inputs", line),
                                   lines[starts[0] + 1:])
        entry = "".join("".join([lines[starts[0]], *rest]).split())
        assert "".join(item.split()) in entry, (attempt, output)
        assert "".join(expected.split()) in "".join(output.split()), (attempt, output)
        rows = _rows(db_url, collection)
        assert {k for k, r in rows.items() if r["status"] == "ok"} == goods, (attempt, output)  # the bad one not
        assert all(not r.get("maps") and not r.get("mesh_blob") for r in rows.values() if r["status"] != "ok")
        assert attempt == "first" or rows == stored, "a second run rewrote rows"  # idempotent
        stored = rows


def test_a_poison_sidecar_keeps_another_folders_material_of_its_name(db_url: str, tmp_path: Path) -> None:
    """A bad folder `a_bad` must not wipe the good material `a_bad` another folder's sidecar named."""
    root = tmp_path / "in"
    write_png(root / "0_good" / "albedo.png", np.full((4, 4, 3), 90, np.uint8))
    (root / "0_good" / "material.json").write_text(_json(name="a_bad"))
    _sidecar(_json(scale="abc"))(root)
    result = runner.invoke(app, ["ingest", "materials", str(root), "--no-previews"])
    assert result.exit_code == 2 and "is kept" in " ".join(result.output.split()), result.output
    with session_scope(db_url) as session:
        row = session.execute(sa.select(m.Material)).scalar_one()
        assert (row.name, row.status, row.enabled, set(row.maps)) == ("a_bad", "ok", True, {"albedo"})
        assert row.source_path == str((root / "0_good").resolve())
