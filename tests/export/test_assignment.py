"""assignment.json sidecar and the per-PhotoShape download folder."""

from __future__ import annotations

import json

import pytest

from photoshape_flow.export.assignment import PartAssignment, Provenance, assignment_document
from photoshape_flow.export.bundle import export_photoshape
from photoshape_flow.export.formats import parse_formats


def _document() -> dict:
    return assignment_document(
        pair_id=3,
        method_key="classifier:1",
        shape=Provenance("shape", 1, "chair-a", "shapenet", "ShapeNet terms", "ShapeNet", "https://shapenet.org"),
        exemplar=Provenance("exemplar", 2, "photo-9", "demo", "CC-BY-4.0", "A. Photographer", None),
        parts=[
            PartAssignment(1, "seat", 10, "oak_01", "wood", 0.83, uv_density=4.0, material_scale=0.25,
                           uv_transform={"scale": 1.5, "rotation": 0.2, "offset": [0.1, 0.0]}),
            PartAssignment(2, "leg", None, None, "metal", None, unobserved=True),
        ],
        materials=[Provenance("material", 10, "oak_01", "demo", "CC0-1.0", "photoshape demo", None),
                   Provenance("material", 10, "oak_01", "demo", "CC0-1.0", "photoshape demo", None)],
        envmap=Provenance("envmap", 5, "studio", "demo", None, None, None),
        camera={"azimuth": 0.1, "elevation": 0.2, "distance": 2.0, "fov": 50.0},
    )


def test_document_lists_every_licence_once():
    doc = _document()
    roles = [(x["role"], x["name"]) for x in doc["licenses"]]
    assert roles == [("shape", "chair-a"), ("exemplar", "photo-9"), ("material", "oak_01"), ("envmap", "studio")]
    assert doc["license_summary"] == ["CC-BY-4.0", "CC0-1.0", "ShapeNet terms"]
    assert doc["unknown_licenses"] == 1  # the envmap has none recorded
    seat, leg = doc["parts"]
    assert seat["material"] == {"id": 10, "name": "oak_01"} and seat["score"] == pytest.approx(0.83)
    # texture-scale formula: 1/sqrt(4) / 0.25 = 2, times the jitter's 1.5
    assert seat["uv"]["matrix"][0][0] == pytest.approx(3.0 * __import__("math").cos(0.2), rel=1e-6)
    assert leg["builtin"] and leg["material"] is None and leg["unobserved"]


def test_bundle_writes_formats_and_sidecar(tmp_path, tiny_shape, tiny_materials):
    doc = _document()
    written = export_photoshape(tmp_path / "3", tiny_shape, [tiny_materials[0], None], None, doc,
                                formats=["glb", "gltf", "obj"])
    assert set(written) == {"glb", "gltf", "obj", "assignment"}
    assert all(path.is_file() for path in written.values())
    sidecar = json.loads(written["assignment"].read_text())
    assert sidecar["license_summary"] == ["CC-BY-4.0", "CC0-1.0", "ShapeNet terms"]
    attribution = (tmp_path / "3" / "ATTRIBUTION.txt").read_text()
    assert "exemplar photo-9: CC-BY-4.0, A. Photographer" in attribution
    assert "shape chair-a: ShapeNet terms" in (tmp_path / "3" / "photoshape.mtl").read_text()
    # re-export replaces the folder atomically (no leftovers, no temporary siblings)
    export_photoshape(tmp_path / "3", tiny_shape, None, None, doc, formats=["glb"])
    assert sorted(p.name for p in (tmp_path / "3").iterdir()) == ["ATTRIBUTION.txt", "assignment.json",
                                                                  "photoshape.glb"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["3", "maps"]


def test_unknown_format_is_one_line_error():
    assert parse_formats("glb, XML") == ("glb", "xml")
    with pytest.raises(ValueError, match="unknown export format.*fbx.*valid: glb, gltf, xml, obj"):
        parse_formats("glb,fbx")
