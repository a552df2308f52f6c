"""The export-format table: every consumer reads it, so one line and one writer are one new format."""

from __future__ import annotations

import zipfile
from pathlib import Path

from photoshape_flow.export.bundle import export_photoshape
from photoshape_flow.export.formats import DEFAULT_FORMATS, EXPORTERS, SIDECAR, ExportFormat, parse_formats
from photoshape_flow.export.gallery import DOWNLOAD_LABELS, _download
from photoshape_flow.export.writers import WRITERS, ExportInput

DOCUMENT = {"licenses": [{"role": "shape", "name": "stool", "license": "CC0-1.0", "attribution": "A. Maker"}]}

# a format that exists only in this test: the part names, one a line
PART_NAMES = ExportFormat("names", "names/parts.txt", "part names")


def write_part_names(target: Path, item: ExportInput) -> None:
    target.parent.mkdir(parents=True)
    target.write_text("\n".join([*item.attribution, *(part.name for part in item.shape.parts)]) + "\n")


def test_registry_keys_defaults_and_paths() -> None:
    assert list(EXPORTERS) == ["glb", "gltf", "xml", "obj"]
    assert all(name == fmt.name for name, fmt in EXPORTERS.items())
    assert set(WRITERS) == set(EXPORTERS)  # a writer for every format, no writer without one
    assert DEFAULT_FORMATS == ("glb", "xml", "obj")
    paths = [fmt.path for fmt in EXPORTERS.values()]
    assert len(set(paths)) == len(paths) and "assignment.json" not in paths


def test_gallery_labels_come_from_the_registry() -> None:
    assert DOWNLOAD_LABELS == {
        "glb": "glTF binary (.glb)", "gltf": "glTF + textures (.zip)", "xml": "Mitsuba 3 scene (.zip)",
        "obj": "OBJ + MTL + textures (.zip)", SIDECAR: "assignment.json",
    }


def test_a_registered_format_is_written(tmp_path: Path, tiny_shape, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setitem(EXPORTERS, "names", PART_NAMES)
    monkeypatch.setitem(WRITERS, "names", write_part_names)
    assert parse_formats("Names, glb") == ("names", "glb")
    written = export_photoshape(tmp_path / "7", tiny_shape, None, None, DOCUMENT, formats=["names"])
    assert written == {"names": tmp_path / "7" / "names" / "parts.txt", SIDECAR: tmp_path / "7" / "assignment.json"}
    lines = written["names"].read_text().splitlines()
    assert lines == ["shape stool: CC0-1.0, A. Maker", *(part.name for part in tiny_shape.parts)]
    # the gallery offers a multi-file format as a zip of its folder
    href = _download(tmp_path / "site", "7", "names", written["names"])
    assert href == "downloads/7/names.zip"
    with zipfile.ZipFile(tmp_path / "site" / href) as zf:
        assert zf.namelist() == ["names/parts.txt"]


def test_identical_textures_are_written_once_per_bundle(tmp_path: Path, tiny_shape, tiny_materials) -> None:
    """One material on both parts, exported in every format: each distinct texture is one file, named
    by content, that the glTF and the OBJ both reference; the downloads carry what they reference."""
    import hashlib
    import json
    import re

    from photoshape_flow.render.camera import Camera

    oak = tiny_materials[0]
    written = export_photoshape(tmp_path / "7", tiny_shape, [oak, oak], None, DOCUMENT, formats=list(EXPORTERS),
                                camera=Camera(0.5, 0.3, 2.0, 40.0), size=8, spp=1)
    bundle = tmp_path / "7"
    images = [p for p in bundle.rglob("*") if p.suffix in (".png", ".jpg", ".exr")]
    digests = [hashlib.sha256(p.read_bytes()).hexdigest() for p in images]
    assert len(set(digests)) == len(digests) > 0  # no two texture files hold the same bytes
    shared = sorted(p.name for p in (bundle / "textures").iterdir())
    assert shared and all(re.fullmatch(r"[0-9a-f]{16}\.png", name) for name in shared)
    gltf_uris = {image["uri"] for image in json.loads(written["gltf"].read_text())["images"]}
    mtl_refs = set(re.findall(r"(?<!\S)(\S*textures/\S+)", (bundle / "photoshape.mtl").read_text()))
    assert gltf_uris and mtl_refs and all(ref.startswith("textures/") for ref in gltf_uris | mtl_refs)
    assert all((written["gltf"].parent / ref).is_file() for ref in gltf_uris | mtl_refs)
    basecolor = re.search(r"^map_Kd (\S+)$", (bundle / "photoshape.mtl").read_text(), re.M)
    assert basecolor is not None and basecolor.group(1) in gltf_uris  # both formats use the one copy
    xml = written["xml"].read_text()
    assert len(re.findall(r'value="(textures/[0-9a-f]{16}\.exr)"', xml)) > len(set(re.findall(
        r'value="(textures/[0-9a-f]{16}\.exr)"', xml)))  # both parts name the same EXR files
    # a download of the glTF is what it names, transitively, and nothing of the other formats
    href = _download(tmp_path / "site", "7", "gltf", written["gltf"])
    with zipfile.ZipFile(tmp_path / "site" / str(href)) as zf:
        names = set(zf.namelist())
        zf.extractall(tmp_path / "unpacked")
    assert names == {"gltf/photoshape.gltf", "gltf/photoshape.bin", *(f"gltf/{ref}" for ref in gltf_uris)}
    href = _download(tmp_path / "site", "7", "obj", written["obj"])
    with zipfile.ZipFile(tmp_path / "site" / str(href)) as zf:
        assert set(zf.namelist()) == {"obj/photoshape.obj", "obj/photoshape.mtl", *(f"obj/{ref}" for ref in mtl_refs)}
