"""Fixtures of the export tests (data made by tests/export/tiny.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from tests.export.tiny import make_material_maps, make_tiny_shape

from photoshape_flow.geometry.mesh import ShapeMesh


@pytest.fixture
def tiny_shape() -> ShapeMesh:
    return make_tiny_shape()


@pytest.fixture
def tiny_materials(tmp_path: Path):  # type: ignore[no-untyped-def]
    """Two SVBRDF MaterialSpecs: 'oak_01' (scale 0.25, wood) and 'steel_02' (scale 0.5, metal)."""
    from photoshape_flow.render import MaterialSpec

    maps = make_material_maps(tmp_path / "maps")
    return [
        MaterialSpec(name="oak_01", substance="wood", scale=0.25, maps=maps["oak_01"]),
        MaterialSpec(name="steel_02", substance="metal", scale=0.5, maps=maps["steel_02"]),
    ]
