"""Hypothesis strategies for hostile inputs, one per reader, each drawing from at least ten kinds.

Each reader's function returns its kinds by name, each kind a strategy for the files to write
(relative path -> bytes), so a failure names the kind that found it. Valid seeds (a chair OBJ, a GLB, a catalog, a
photo, a sky) are built once and then truncated, flipped, stretched or rewritten; the rest is
generated from scratch. Everything stays small on disk: the hostility is in what the bytes claim
(canvases, counts, digits, depths), not in their size, so the harness stays fast.
"""

from __future__ import annotations

import io
import json
import struct
import tempfile
import zipfile
import zlib
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np
from hypothesis import strategies as st
from tests.geometry.makers import chair_members, properties_text, write_chair_obj, write_glb

Files = dict[str, bytes]
Kinds = dict[str, st.SearchStrategy[Files]]

# names and text that other readers refuse or must escape: controls, bidi, markup, surrogates avoided
HOSTILE_CHARS = st.sampled_from(["\n", "\r", "\x00", "\x1b[31m", "\u202e", "\u2066", "\u200f", "<script>", "[/red]",
                                 "../", "/", "\\", " ", "\t", "é", "\ufeff", "\u0085"])
hostile_text = st.lists(st.one_of(HOSTILE_CHARS, st.text(max_size=8)), max_size=6).map("".join)
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | hostile_text,
    lambda children: st.lists(children, max_size=4) | st.dictionaries(hostile_text, children, max_size=4),
    max_leaves=12,
)


def kinds(**strategies: st.SearchStrategy[Files]) -> dict[str, st.SearchStrategy[Files]]:
    """A reader's kinds by name: the harness fuzzes each one on its own, so every kind is always drawn."""
    return dict(strategies)


def flips(seed: bytes) -> st.SearchStrategy[bytes]:
    """`seed` with up to eight bytes overwritten at drawn positions."""
    edits = st.lists(st.tuples(st.integers(0, len(seed) - 1), st.integers(0, 255)), min_size=1, max_size=8)

    def apply(changes: list[tuple[int, int]]) -> bytes:
        data = bytearray(seed)
        for position, value in changes:
            data[position] = value
        return bytes(data)

    return edits.map(apply)


def truncations(seed: bytes) -> st.SearchStrategy[bytes]:
    return st.integers(0, len(seed) - 1).map(lambda n: seed[:n])


def _png(array: np.ndarray, **params: object) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, "PNG", **params)
    return buffer.getvalue()


def _encoded(array: np.ndarray, fmt: str) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, fmt)
    return buffer.getvalue()


def png_declaring(width: int, height: int, depth: int = 8, colour: int = 2, payload: bytes = b"\x00" * 64) -> bytes:
    """A PNG whose IHDR claims any canvas, followed by a tiny IDAT."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(payload)) + chunk(b"IEND", b"")


@cache
def photo_png() -> bytes:
    """A valid product photo: a dark box on white."""
    array = np.full((48, 64, 3), 250, np.uint8)
    array[10:40, 20:44] = (90, 60, 30)
    return _png(array)


# --- material sidecars ----------------------------------------------------------------------------

ALBEDO = _png(np.full((4, 4, 3), 120, np.uint8))


def _material(sidecar: bytes, name: str = "material.json", extra: Files | None = None) -> Files:
    return {name: sidecar, "albedo.png": ALBEDO, **(extra or {})}


def _json(**fields: object) -> bytes:
    return json.dumps({"substance": "wood", **fields}, allow_nan=True).encode("utf-8", "surrogatepass")


SIDECAR_FIELDS = st.sampled_from(["scale", "name", "substance", "kind", "normal", "params", "maps", "source",
                                  "license", "attribution", "source_url"])


def json_sidecars() -> Kinds:
    digits = st.integers(25, 6000).map(lambda n: "7" * n)
    return kinds(
        random_document=json_values.map(lambda v: _material(json.dumps(v).encode("utf-8", "surrogatepass"))),
        random_field=st.tuples(SIDECAR_FIELDS, json_values).map(lambda kv: _material(_json(**{kv[0]: kv[1]}))),
        long_integer=st.tuples(SIDECAR_FIELDS, digits).map(
            lambda kv: _material(b'{"substance": "wood", "%s": %s}' % (kv[0].encode(), kv[1].encode()))),
        huge_exponent=st.integers(20, 400).map(
            lambda n: _material(b'{"substance": "wood", "scale": 1e%d}' % n)),
        non_finite=st.sampled_from(["NaN", "Infinity", "-Infinity"]).map(
            lambda c: _material(b'{"substance": "wood", "params": {"roughness": %s}}' % c.encode())),
        deep_nesting=st.tuples(st.integers(20, 3000), st.sampled_from(["[", '{"a":'])).map(
            lambda d: _material(b'{"substance": "wood", "x": ' + d[1].encode() * d[0] + b"1"
                                + (b"]" if d[1] == "[" else b"}") * d[0] + b"}")),
        random_bytes=st.binary(max_size=200).map(_material),
        truncated=st.tuples(json_values, st.integers(0, 40)).map(
            lambda v: _material(_json(params=v[0])[: v[1]])),
        hostile_name=hostile_text.map(lambda name: _material(_json(name=name))),
        map_outside=st.sampled_from(["../albedo.png", "/etc/passwd", "../../x.png", "sub/../../y.png", "", ".",
                                     "albedo.png\x00"]).map(lambda f: _material(_json(maps={"albedo": f}))),
        huge_string=st.integers(900_000, 1_100_000).map(lambda n: _material(_json(attribution="a" * n))),
        albedo_bytes=st.one_of(truncations(ALBEDO), flips(ALBEDO), st.just(png_declaring(70_000, 70_000))).map(
            lambda data: {"material.json": _json(), "albedo.png": data}),
    )


def _toml_value() -> st.SearchStrategy[str]:
    return st.one_of(
        st.integers().map(str), st.floats(allow_nan=True, allow_infinity=True).map(
            lambda f: "nan" if f != f else ("inf" if f > 0 else "-inf") if abs(f) == float("inf") else repr(f)),
        hostile_text.map(json.dumps), st.booleans().map(lambda b: str(b).lower()),
    )


def toml_sidecars() -> Kinds:
    def doc(lines: str) -> Files:
        return _material(lines.encode("utf-8", "surrogatepass"), "material.toml")

    return kinds(
        random_field=st.tuples(SIDECAR_FIELDS, _toml_value()).map(
            lambda kv: doc(f'substance = "wood"\n{kv[0]} = {kv[1]}\n')),
        long_integer=st.integers(25, 6000).map(lambda n: doc('substance = "wood"\nscale = ' + "7" * n + "\n")),
        special_float=st.sampled_from(["nan", "inf", "-inf", "+nan", "1e400", "-1e400", "1e308"]).map(
            lambda v: doc(f'substance = "wood"\nscale = {v}\n')),
        deep_array=st.integers(20, 3000).map(lambda n: doc('substance = "wood"\nx = ' + "[" * n + "]" * n + "\n")),
        deep_inline_table=st.integers(20, 300).map(lambda n: doc('substance = "wood"\nx = ' + "{a = " * n + "1"
                                                                  + "}" * n + "\n")),
        random_text=st.text(max_size=200).map(doc),
        random_bytes=st.binary(max_size=200).map(lambda b: _material(b, "material.toml")),
        hostile_name=hostile_text.map(lambda name: doc(f'substance = "wood"\nname = {json.dumps(name)}\n')),
        params_table=st.dictionaries(st.sampled_from(["roughness", "metallic", "specular", "albedo", "x"]),
                                     _toml_value(), max_size=4).map(
            lambda p: doc('substance = "wood"\n[params]\n' + "".join(f"{k} = {v}\n" for k, v in p.items()))),
        unterminated=st.sampled_from(['name = "abc', "name = '''abc", 'name = """', "[params", "x = [1, 2",
                                      "a.b.c = 1\na = 2"]).map(lambda line: doc('substance = "wood"\n' + line + "\n")),
        maps_table=st.sampled_from(["../albedo.png", "/etc/passwd", "missing.png", "albedo.png"]).map(
            lambda f: doc(f'substance = "wood"\n[maps]\nalbedo = {json.dumps(f)}\n')),
    )


# --- OBJ / MTL ---------------------------------------------------------------------------------------

@cache
def chair_obj() -> tuple[bytes, bytes]:
    with tempfile.TemporaryDirectory() as scratch:
        obj = write_chair_obj(Path(scratch), "chair")
        return obj.read_bytes(), obj.with_suffix(".mtl").read_bytes()


NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers().map(str),
                    st.sampled_from(["1e308", "-1e308", "nan", "inf", "1e-320", "0x10", "", "-", "1,5"]))
TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


def _obj(text: str, mtl: str | None = None) -> Files:
    files = {"model.obj": text.encode("utf-8", "surrogatepass")}
    if mtl is not None:
        files["model.mtl"] = mtl.encode("utf-8", "surrogatepass")
    return files


def objs() -> Kinds:
    obj, mtl = chair_obj()
    vertex = st.lists(NUMBERS, min_size=0, max_size=5).map(lambda xs: "v " + " ".join(xs))
    index = st.one_of(st.integers(-5, 5), st.integers(), st.sampled_from(["1/2/3", "1//", "//", "a", "0"])).map(str)
    face = st.lists(index, min_size=0, max_size=6).map(lambda xs: "f " + " ".join(xs))
    return kinds(
        vertices=st.lists(vertex, min_size=3, max_size=8).map(lambda vs: _obj("\n".join(vs) + "\nf 1 2 3\n")),
        faces=st.lists(face, max_size=8).map(lambda fs: _obj(TRIANGLE + "\n".join(fs) + "\n")),
        absurd_coordinates=st.sampled_from(["1e308", "-1e308", "1e200", "3.4e38", "1e13"]).map(
            lambda x: _obj(f"v {x} 0 0\nv 0 {x} 0\nv 0 0 1\nf 1 2 3\n")),
        part_names=hostile_text.map(lambda name: _obj(f"usemtl {name}\n" + TRIANGLE + "f 1 2 3\n")),
        group_names=hostile_text.map(lambda name: _obj(f"o {name}\ng {name}\n" + TRIANGLE + "f 1 2 3\n")),
        mtllib=st.tuples(hostile_text, st.text(max_size=120)).map(
            lambda m: _obj("mtllib model.mtl\nusemtl a\n" + TRIANGLE + "f 1 2 3\n", f"newmtl a\n{m[1]}\n")),
        mtl_values=st.lists(st.tuples(st.sampled_from(["Kd", "Ks", "Ns", "d", "Tr", "Pr", "Pm", "map_Kd", "Ke"]),
                                      st.lists(NUMBERS, max_size=4)), max_size=6).map(
            lambda kv: _obj("mtllib model.mtl\nusemtl a\n" + TRIANGLE + "f 1 2 3\n",
                            "newmtl a\n" + "".join(f"{k} {' '.join(v)}\n" for k, v in kv))),
        texture_path=st.sampled_from(["../../etc/passwd", "/etc/passwd", "C:\\x\\y.png", "missing.png", "tex",
                                      "model.obj"]).map(
            lambda p: _obj("mtllib model.mtl\nusemtl a\nvt 0 0\nvt 1 0\nvt 0 1\n" + TRIANGLE + "f 1/1 2/2 3/3\n",
                           f"newmtl a\nmap_Kd {p}\n")),
        truncated=truncations(obj).map(lambda data: {"model.obj": data, "chair.mtl": mtl}),
        flipped=flips(obj).map(lambda data: {"model.obj": data, "chair.mtl": mtl}),
        random_bytes=st.binary(max_size=300).map(lambda data: {"model.obj": data}),
        long_line=st.integers(10_000, 300_000).map(lambda n: _obj("v " + "1 " * n + "\n" + TRIANGLE + "f 1 2 3\n")),
    )


# --- glTF / GLB --------------------------------------------------------------------------------------

@cache
def glb_seed() -> bytes:
    with tempfile.TemporaryDirectory() as scratch:
        return write_glb(Path(scratch) / "seed.glb").read_bytes()


def _glb_with_json(document: object, binary: bytes = b"") -> bytes:
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text
    if binary:
        binary += b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def _accessor_doc(count: int, component: int, kind: str, byte_length: int) -> dict[str, object]:
    return {"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "scene": 0, "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
            "buffers": [{"byteLength": byte_length}],
            "bufferViews": [{"buffer": 0, "byteLength": byte_length}],
            "accessors": [{"bufferView": 0, "componentType": component, "count": count, "type": kind},
                          {"bufferView": 0, "componentType": 5125, "count": count, "type": "SCALAR"}]}


def gltfs() -> Kinds:
    seed = glb_seed()
    return kinds(
        glb_truncated=truncations(seed).map(lambda data: {"model.glb": data}),
        glb_flipped=flips(seed).map(lambda data: {"model.glb": data}),
        glb_header_length=st.integers(0, 2**32 - 1).map(
            lambda n: {"model.glb": seed[:8] + struct.pack("<I", n) + seed[12:]}),
        glb_chunk_length=st.integers(0, 2**32 - 1).map(
            lambda n: {"model.glb": seed[:12] + struct.pack("<I", n) + seed[16:]}),
        glb_random_json=json_values.map(lambda doc: {"model.glb": _glb_with_json(doc)}),
        accessor_counts=st.tuples(st.integers(0, 2**31), st.sampled_from([5120, 5121, 5123, 5125, 5126, 1, 0]),
                                  st.sampled_from(["VEC3", "SCALAR", "MAT4", "X"]), st.integers(0, 4096)).map(
            lambda a: {"model.glb": _glb_with_json(_accessor_doc(*a), b"\0" * min(a[3], 4096))}),
        gltf_random_json=json_values.map(lambda doc: {"model.gltf": json.dumps(doc).encode("utf-8", "surrogatepass")}),
        gltf_buffer_uri=st.sampled_from(["../../etc/passwd", "/etc/passwd", "data:application/octet-stream;base64,!!",
                                         "data:,", "missing.bin", "model.gltf", "http://example.com/x.bin"]).map(
            lambda uri: {"model.gltf": json.dumps({**_accessor_doc(3, 5126, "VEC3", 36),
                                                   "buffers": [{"byteLength": 36, "uri": uri}]}).encode()}),
        gltf_deep=st.integers(20, 3000).map(lambda n: {"model.gltf": b"[" * n + b"]" * n}),
        gltf_long_integer=st.integers(25, 6000).map(
            lambda n: {"model.gltf": b'{"asset": {"version": "2.0"}, "scene": ' + b"9" * n + b"}"}),
        random_bytes=st.binary(max_size=300).map(lambda data: {"model.glb": data}),
    )


# --- Sweet Home 3D catalogs ---------------------------------------------------------------------------

CHAIR_ENTRY = {"id": "T#chair", "name": "Chair", "category": "Living room", "tags": "", "creator": "X",
               "model": "/t/chair/chair.obj"}


def _zip(members: dict[str, bytes], properties: str | bytes | None = None) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf:
        if properties is not None:
            data = properties.encode("latin-1", "replace") if isinstance(properties, str) else properties
            zf.writestr("PluginFurnitureCatalog.properties", data)
        for name, data in members.items():
            zf.writestr(name, data)
    return buffer.getvalue()


@cache
def sh3f_seed() -> bytes:
    return _zip(chair_members("t/chair"), properties_text([CHAIR_ENTRY]))


def sh3fs() -> Kinds:
    seed = sh3f_seed()
    members = chair_members("t/chair")
    entry_field = st.sampled_from(["id", "name", "category", "model", "creator", "modelRotation", "width",
                                   "modelSize", "doorOrWindow", "multiPartModel"])
    catalog = lambda entries: {"catalog.sh3f": _zip(members, properties_text(entries))}  # noqa: E731
    return kinds(
        truncated=truncations(seed).map(lambda data: {"catalog.sh3f": data}),
        flipped=flips(seed).map(lambda data: {"catalog.sh3f": data}),
        random_field=st.tuples(entry_field, hostile_text).map(lambda kv: catalog([{**CHAIR_ENTRY, kv[0]: kv[1]}])),
        model_path=st.sampled_from(["/../../etc/passwd", "../../x.obj", "/t/chair/missing.obj", "", "/", "//x",
                                    "/t/chair/chair.mtl", "C:\\x.obj", "/t/chair/chair.obj\x00"]).map(
            lambda p: catalog([{**CHAIR_ENTRY, "model": p}])),
        rotation=st.lists(NUMBERS, max_size=10).map(
            lambda xs: catalog([{**CHAIR_ENTRY, "modelRotation": " ".join(xs)}])),
        many_entries=st.integers(2, 40).map(lambda n: catalog([{**CHAIR_ENTRY, "id": f"T#c{i}"} for i in range(n)])),
        member_bomb=st.integers(2, 12).map(lambda mb: {"catalog.sh3f": _zip(
            {**members, "t/chair/chair.obj": members["t/chair/chair.obj"] + b" " * (mb << 20)},
            properties_text([CHAIR_ENTRY]))}),
        member_names=hostile_text.map(lambda name: {"catalog.sh3f": _zip(
            {f"t/{name}/chair.obj": members["t/chair/chair.obj"]},
            properties_text([{**CHAIR_ENTRY, "model": f"/t/{name}/chair.obj"}]))}),
        hostile_model=st.binary(max_size=300).map(lambda data: {"catalog.sh3f": _zip(
            {"t/chair/chair.obj": data}, properties_text([CHAIR_ENTRY]))}),
        properties_bytes=st.binary(max_size=300).map(lambda data: {"catalog.sh3f": _zip(members, data)}),
        not_a_zip=st.binary(max_size=300).map(lambda data: {"catalog.sh3f": data}),
        no_catalog=st.just({"catalog.sh3f": _zip(members)}),
    )


# --- images (exemplar photos) --------------------------------------------------------------------------

def images() -> Kinds:
    seed = photo_png()
    size = st.integers(1, 2**31 - 1)
    noise = st.tuples(st.integers(1, 64), st.integers(1, 64), st.sampled_from(["L", "RGB", "RGBA", "LA", "P", "1",
                                                                                 "I;16"]), st.integers(0, 2**32 - 1))

    def noise_png(spec: tuple[int, int, str, int]) -> Files:
        from PIL import Image

        width, height, mode, seed_ = spec
        rng = np.random.default_rng(seed_)
        if mode == "I;16":
            image = Image.fromarray(rng.integers(0, 65535, (height, width), dtype=np.uint16))
        else:
            image = Image.fromarray(rng.integers(0, 255, (height, width, 3), dtype=np.uint8)).convert(mode)
        buffer = io.BytesIO()
        image.save(buffer, "PNG")
        return {"photo.png": buffer.getvalue()}

    array = np.full((48, 64, 3), 250, np.uint8)
    array[10:40, 20:44] = (90, 60, 30)
    return kinds(
        declared_canvas=st.tuples(size, size).map(lambda wh: {"photo.png": png_declaring(*wh)}),
        strip=st.tuples(st.integers(21, 4000), st.booleans()).map(
            lambda s: {"photo.png": _png(np.zeros((2, 2 * s[0]) if s[1] else (2 * s[0], 2), np.uint8))}),
        truncated_png=truncations(seed).map(lambda data: {"photo.png": data}),
        flipped_png=flips(seed).map(lambda data: {"photo.png": data}),
        truncated_jpeg=truncations(_encoded(array, "JPEG")).map(lambda data: {"photo.jpg": data}),
        flipped_webp=flips(_encoded(array, "WEBP")).map(lambda data: {"photo.webp": data}),
        noise=noise.map(noise_png),
        wrong_format=st.sampled_from(["GIF", "BMP", "TIFF", "ICO"]).map(
            lambda fmt: {"photo.png": _encoded(array, fmt)}),
        bad_depth=st.tuples(st.sampled_from([1, 2, 4, 8, 16, 3, 0, 255]), st.sampled_from([0, 2, 3, 4, 6, 1, 7])).map(
            lambda dc: {"photo.png": png_declaring(64, 48, dc[0], dc[1], b"\x01" * 4000)}),
        exif=st.integers(0, 2**16 - 1).map(lambda o: {"photo.jpg": _jpeg_with_orientation(array, o)}),
        random_bytes=st.binary(max_size=300).map(lambda data: {"photo.png": data}),
        valid=st.just({"photo.png": seed}),
    )


def _jpeg_with_orientation(array: np.ndarray, orientation: int) -> bytes:
    from PIL import Image

    exif = Image.Exif()
    exif[0x0112] = orientation
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, "JPEG", exif=exif.tobytes())
    return buffer.getvalue()


# --- HDR / EXR envmaps ----------------------------------------------------------------------------------

def _hdr(array: np.ndarray) -> bytes:
    import cv2

    ok, data = cv2.imencode(".hdr", np.ascontiguousarray(array[..., ::-1], np.float32))
    assert ok
    return data.tobytes()


def _exr(array: np.ndarray) -> bytes:
    import mitsuba as mi

    with tempfile.TemporaryDirectory() as scratch:
        path = Path(scratch) / "a.exr"
        mi.Bitmap(np.ascontiguousarray(array, np.float32)).write(str(path))
        return path.read_bytes()


@cache
def sky_hdr() -> bytes:
    return _hdr(_sky())


@cache
def sky_exr() -> bytes:
    return _exr(_sky())


def _sky(width: int = 32, height: int = 16) -> np.ndarray:
    rows = np.linspace(2.0, 0.1, height, dtype=np.float32)[:, None, None]
    return np.broadcast_to(rows, (height, width, 3)).copy()


SPECIAL = st.sampled_from([float("nan"), float("inf"), -float("inf"), 1.7e38, -1.7e38, 3.4e38, -1.0, 0.0, 1e-38,
                           1e9, 65504.0])


def envmaps() -> Kinds:
    hdr, exr = sky_hdr(), sky_exr()

    def poked(spec: tuple[list[tuple[int, int, float]], bool]) -> Files:
        array = _sky()
        for y, x, value in spec[0]:
            array[y % 16, x % 32] = value
        return {"sky.exr": _exr(array)} if spec[1] else {"sky.hdr": _hdr(array)}

    header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"
    return kinds(
        special_values=st.tuples(st.lists(st.tuples(st.integers(0, 15), st.integers(0, 31), SPECIAL), min_size=1,
                                          max_size=4), st.booleans()).map(poked),
        all_one_value=st.tuples(SPECIAL, st.booleans()).map(lambda v: poked(([(y, x, v[0]) for y in range(16)
                                                                              for x in range(32)], v[1]))),
        resolution_line=st.tuples(st.sampled_from(["-Y", "+Y", "-X", "Y", ""]), st.integers(-1, 2**40),
                                  st.integers(-1, 2**40)).map(
            lambda r: {"sky.hdr": header + f"{r[0]} {r[1]} +X {r[2]}\n".encode() + b"\x02\x02\x00\x10" * 16}),
        header_text=st.binary(max_size=200).map(lambda b: {"sky.hdr": b"#?RADIANCE\n" + b}),
        hdr_truncated=truncations(hdr).map(lambda data: {"sky.hdr": data}),
        hdr_flipped=flips(hdr).map(lambda data: {"sky.hdr": data}),
        exr_truncated=truncations(exr).map(lambda data: {"sky.exr": data}),
        exr_flipped=flips(exr).map(lambda data: {"sky.exr": data}),
        exr_data_window=st.tuples(*[st.integers(-2**31, 2**31 - 1)] * 4).map(
            lambda w: {"sky.exr": _exr_window(exr, w)}),
        aspect=st.tuples(st.integers(16, 128), st.integers(1, 64)).map(
            lambda wh: {"sky.hdr": _hdr(np.ones((wh[1], wh[0], 3), np.float32))}),
        random_bytes=st.tuples(st.binary(max_size=300), st.booleans()).map(
            lambda b: {"sky.exr" if b[1] else "sky.hdr": b[0]}),
    )


def _exr_window(exr: bytes, window: tuple[int, int, int, int]) -> bytes:
    """`exr` with its dataWindow attribute rewritten (the header's canvas claim)."""
    marker = exr.find(b"dataWindow\0box2i\0")
    if marker < 0:
        return exr
    start = marker + len(b"dataWindow\0box2i\0") + 4
    return exr[:start] + struct.pack("<4i", *window) + exr[start + 16 :]


# --- ground-truth files ---------------------------------------------------------------------------------

def _entry(**fields: object) -> dict[str, object]:
    return {"source_id": "photo", "shape": {"source_id": "chair"},
            "parts": {"seat": {"material": "oak", "substance": "wood"}}, **fields}


def _truth(entries: list[object], **top: object) -> bytes:
    document = {"format": "photoshape-groundtruth", "version": 2, "exemplars": entries, **top}
    return json.dumps(document, allow_nan=True).encode("utf-8", "surrogatepass")


ENTRY_FIELDS = st.sampled_from(["source", "source_id", "shape", "in_collection", "camera", "parts", "mask",
                                "lighting"])


def groundtruths() -> Kinds:
    return kinds(
        random_document=json_values.map(lambda v: {"truth.json": json.dumps(v).encode("utf-8", "surrogatepass")}),
        random_entry=json_values.map(lambda v: {"truth.json": _truth([v])}),
        random_field=st.tuples(ENTRY_FIELDS, json_values).map(
            lambda kv: {"truth.json": _truth([_entry(**{kv[0]: kv[1]})])}),
        camera=st.dictionaries(st.sampled_from(["azimuth", "elevation", "distance", "fov"]),
                               st.one_of(st.floats(allow_nan=True, allow_infinity=True), hostile_text), max_size=4).map(
            lambda c: {"truth.json": _truth([_entry(camera=c)])}),
        mask_values=st.dictionaries(st.one_of(st.integers().map(str), hostile_text), json_values, max_size=4).map(
            lambda v: {"truth.json": _truth([_entry(mask={"path": "m.png", "values": v})])}),
        long_integer=st.integers(25, 6000).map(
            lambda n: {"truth.json": b'{"format": "photoshape-groundtruth", "version": ' + b"2" * n + b"}"}),
        deep_nesting=st.integers(17, 3000).map(lambda n: {"truth.json": b"[" * n + b"]" * n}),
        random_bytes=st.binary(max_size=300).map(lambda data: {"truth.json": data}),
        json_lines=st.lists(st.one_of(json_values.map(json.dumps), st.text(max_size=40)), max_size=5).map(
            lambda lines: {"truth.jsonl": ('{"format": "photoshape-groundtruth", "version": 2}\n'
                                           + "\n".join(lines)).encode("utf-8", "surrogatepass")}),
        version=st.one_of(json_values, st.integers()).map(lambda v: {"truth.json": json.dumps(
            {"format": "photoshape-groundtruth", "version": v, "exemplars": []}).encode("utf-8", "surrogatepass")}),
        duplicates=st.integers(2, 50).map(lambda n: {"truth.json": _truth([_entry()] * n)}),
        hostile_names=hostile_text.map(lambda name: {"truth.json": _truth([_entry(source_id=name, parts={
            name: {"material": name, "substance": name}})])}),
    )


READERS: dict[str, Callable[[], Kinds]] = {
    "json_sidecars": json_sidecars, "toml_sidecars": toml_sidecars, "objs": objs, "gltfs": gltfs, "sh3fs": sh3fs,
    "images": images, "envmaps": envmaps, "groundtruths": groundtruths,
}
