"""Security: hostile metadata stays inert text in every exported text format.

Attribution, licence, names and source URLs are anyone's text. A newline in an attribution must not
become a live line (``mtllib /etc/passwd``) in OBJ/MTL, and no control or bidi character reaches
ATTRIBUTION.txt, glTF JSON or Mitsuba XML (`photoshape_flow.export.text`).
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import pytest

from photoshape_flow.export.bundle import export_photoshape
from photoshape_flow.export.text import is_web_url, one_line, one_line_strings
from photoshape_flow.render.camera import Camera

INJECTED = "mtllib /etc/passwd"
HOSTILE = f"A. Maker\n{INJECTED}\r\nusemtl evil\u2028f 1 2 3\x1b[31m\u202egnp.exe\x00"
DOCUMENT = {
    "licenses": [
        {"role": "shape", "name": f"stool\n{INJECTED}", "license": f"CC0-1.0\r{INJECTED}", "attribution": HOSTILE,
         "source_url": f"https://example.org/x\n{INJECTED}"},
        {"role": "material", "name": "oak_01", "license": "CC-BY-4.0\u0085usemtl evil", "attribution": "B\vC",
         "source_url": None},
    ],
}
# anything a text export may hold besides its own line breaks
FORBIDDEN = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")
OBJ_STATEMENTS = {"mtllib", "o", "g", "v", "vt", "vn", "usemtl", "f"}
MTL_STATEMENTS = {"newmtl", "Ka", "Kd", "Ks", "Ns", "illum", "Pr", "Pm", "map_Kd", "map_Pr", "map_Pm", "norm",
                  "map_Bump"}


def _strings(value: Any) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in (*_strings(k), *_strings(v))]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return []


def test_one_line_and_web_urls() -> None:
    assert one_line("a\r\nb\u2028c\td") == "a b c d"
    assert one_line("x\x1b[0m\u202eyz\x00") == "x\\u001b[0m\\u202eyz\\u0000"
    assert one_line(None) == "" and one_line(one_line(HOSTILE)) == one_line(HOSTILE)
    assert one_line_strings({"k\n": ["a\nb", 1, None]}) == {"k ": ["a b", 1, None]}
    assert is_web_url("https://example.org/a?b=1") and is_web_url("HTTP://example.org")
    for url in ("javascript:alert(1)", "java\tscript:alert(1)", " https://example.org", "data:,x", "https://",
                "//example.org", "ftp://example.org", "https://exa mple.org", "https://x\n.org", None, ""):
        assert not is_web_url(url), url


@pytest.mark.render
def test_exports_keep_hostile_metadata_on_one_line(tmp_path: Path, tiny_shape, tiny_materials) -> None:
    materials = [dataclasses.replace(tiny_materials[0], name=f"oak\n{INJECTED}", substance=f"wood\n{INJECTED}"),
                 tiny_materials[1]]
    written = export_photoshape(tmp_path / "out", tiny_shape, materials, None, DOCUMENT,
                                formats=["obj", "gltf", "glb", "xml"], camera=Camera(0.6, 0.3, 2.0, 50.0),
                                size=16, spp=4, max_texture_size=64)
    out = tmp_path / "out"
    texts = {p.relative_to(out).as_posix(): p.read_text() for p in out.rglob("*")
             if p.suffix in (".obj", ".mtl", ".gltf", ".xml", ".txt", ".json")}
    assert {"photoshape.obj", "photoshape.mtl", "photoshape.gltf", "mitsuba/scene.xml",
            "ATTRIBUTION.txt", "assignment.json"} <= set(texts)
    for name, text in texts.items():
        if name != "assignment.json":  # JSON escapes control characters itself; kept verbatim there
            assert not FORBIDDEN.search(text), (name, FORBIDDEN.search(text))
        live = [line for line in text.splitlines() if not line.lstrip().startswith("#")]
        assert not any(line.lstrip().startswith((INJECTED, "usemtl evil", "f 1 2 3")) for line in live), name

    obj, mtl = texts["photoshape.obj"], texts["photoshape.mtl"]
    for text, allowed in ((obj, OBJ_STATEMENTS), (mtl, MTL_STATEMENTS)):
        statements = {line.split()[0] for line in text.splitlines() if line and not line.startswith("#")}
        assert statements <= allowed, statements - allowed
    assert [line for line in obj.splitlines() if line.startswith("mtllib")] == ["mtllib photoshape.mtl"]
    assert "A. Maker mtllib /etc/passwd usemtl evil f 1 2 3\\u001b[31m\\u202egnp.exe\\u0000" in mtl  # shown, inert

    attribution = texts["ATTRIBUTION.txt"].splitlines()
    assert len(attribution) == len(DOCUMENT["licenses"])
    assert attribution[1] == "material oak_01: CC-BY-4.0 usemtl evil, B C"

    gltf = json.loads(texts["photoshape.gltf"])
    assert not any(FORBIDDEN.search(s) or "\n" in s or "\r" in s for s in _strings(gltf))
    assert gltf["asset"]["copyright"].count(INJECTED) == 4  # name, licence, attribution, url: as text
    glb = (out / "photoshape.glb").read_bytes()
    assert b"\\n" not in glb[20:20 + int.from_bytes(glb[12:16], "little")]  # no escaped newline in its JSON

    assert "/etc/passwd" not in texts["mitsuba/scene.xml"]  # names only reach it as file names
    assert written["xml"] == out / "mitsuba" / "scene.xml"
