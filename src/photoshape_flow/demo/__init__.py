"""Built-in demo collections with ground truth: procedural seating, SVBRDFs, studios and exemplars.

`generate_demo(out_dir, size, seed)` writes a complete input collection (shapes, materials,
envmaps, photo-like exemplars) plus `groundtruth.json`; `load_groundtruth(path)` reads it back as
typed dataclasses for evaluation. Pure science package: no database, no Prefect.
"""

from photoshape_flow.demo.generate import SIZES, DemoManifest, SizePreset, generate_demo
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
