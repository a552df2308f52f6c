"""Built-in demo collections with ground truth: procedural seating, SVBRDFs, studios and exemplars.

`generate_demo(out_dir, size, seed)` writes a complete input collection (shapes, materials,
envmaps, photo-like exemplars) plus `groundtruth.json` in the ground-truth format that `photoshape
eval` reads (docs/evaluation.md); `load_groundtruth(path)` reads it back with the demo's own fields
as typed dataclasses for the benches and experiments. Pure science package: no database, no Prefect.
"""

from photoshape_flow.demo.generate import DemoManifest, generate_demo
from photoshape_flow.demo.groundtruth import (
    CameraTruth,
    ExemplarTruth,
    GroundTruth,
    MaterialTruth,
    PartTruth,
    ShapeTruth,
    load_groundtruth,
    newest_groundtruth,
)
from photoshape_flow.demo.sizes import SIZES, SizePreset

__all__ = [
    "SIZES",
    "CameraTruth",
    "DemoManifest",
    "ExemplarTruth",
    "GroundTruth",
    "MaterialTruth",
    "PartTruth",
    "ShapeTruth",
    "SizePreset",
    "generate_demo",
    "load_groundtruth",
    "newest_groundtruth",
]
