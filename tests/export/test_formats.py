"""The export-format registry: every consumer reads it, so one new class is one new format."""

from __future__ import annotations

import zipfile
from pathlib import Path

from photoshape_flow.export.bundle import export_photoshape
from photoshape_flow.export.formats import DEFAULT_FORMATS, EXPORTERS, SIDECAR, Exporter, ExportInput, parse_formats
from photoshape_flow.export.gallery import DOWNLOAD_LABELS, _download

DOCUMENT = {"licenses": [{"role": "shape", "name": "stool", "license": "CC0-1.0", "attribution": "A. Maker"}]}


class PartNames(Exporter):
    """A format that exists only in this test: the part names, one a line."""

    name = "names"
    path = "names/parts.txt"
    description = "part names"

    def write(self, target: Path, item: ExportInput) -> None:
        target.parent.mkdir(parents=True)
        target.write_text("\n".join([*item.attribution, *(part.name for part in item.shape.parts)]) + "\n")


def test_registry_keys_defaults_and_paths() -> None:
    assert list(EXPORTERS) == ["glb", "gltf", "xml", "obj"]
    assert all(name == exporter.name for name, exporter in EXPORTERS.items())
    assert DEFAULT_FORMATS == ("glb", "xml", "obj")
    paths = [exporter.path for exporter in EXPORTERS.values()]
    assert len(set(paths)) == len(paths) and "assignment.json" not in paths


def test_gallery_labels_come_from_the_registry() -> None:
    assert DOWNLOAD_LABELS == {
        "glb": "glTF binary (.glb)", "gltf": "glTF + textures (.zip)", "xml": "Mitsuba 3 scene (.zip)",
        "obj": "OBJ + MTL + textures (.zip)", SIDECAR: "assignment.json",
    }


def test_a_registered_class_is_a_format(tmp_path: Path, tiny_shape, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setitem(EXPORTERS, "names", PartNames())
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
