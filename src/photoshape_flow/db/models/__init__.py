"""The metadata schema of the whole pipeline, in the paper's vocabulary.

Every table has a natural unique key so that each write is an idempotent upsert; rows produced by
a step that can fail on one item carry `status` + `error`; result rows carry `params_hash`.
Files (meshes, images, maps, features, checkpoints) live in the blob store and rows hold their refs.
Change the schema only through a new Alembic migration (``migrations/versions``).

The tables live in one module per part of the pipeline (`catalog`: ingested inputs, `matching`:
alignment, `recognition`: classification and rendering, `runs`: evaluation and bookkeeping); this
package names them all, so callers write `from photoshape_flow.db import models as m` and `m.Shape`,
and importing it registers every table on `Base.metadata` (what Alembic compares against).
"""

from __future__ import annotations

from photoshape_flow.db.base import Base
from photoshape_flow.db.models.catalog import Envmap, Exemplar, Material, Part, Shape
from photoshape_flow.db.models.matching import (
    Alignment,
    ExemplarFeature,
    ExemplarMatch,
    Pair,
    ViewFeature,
    ViewpointSet,
)
from photoshape_flow.db.models.recognition import Assignment, Classifier, PartSubstance, Rendering
from photoshape_flow.db.models.runs import Evaluation, Grade, GroundTruthFileRow, PipelineRun, WorkClaim

ALL_TABLES: tuple[type[Base], ...] = (
    Shape, Part, Exemplar, Material, Envmap, ViewpointSet, ViewFeature, ExemplarFeature, ExemplarMatch,
    Pair, Alignment, PartSubstance, Rendering, Classifier, Assignment, Evaluation, GroundTruthFileRow, Grade,
    WorkClaim, PipelineRun,
)

__all__ = [
    "ALL_TABLES", "Alignment", "Assignment", "Classifier", "Envmap", "Evaluation", "Exemplar", "ExemplarFeature",
    "ExemplarMatch", "Grade", "GroundTruthFileRow", "Material", "Pair", "Part", "PartSubstance", "PipelineRun",
    "Rendering", "Shape", "ViewFeature", "ViewpointSet", "WorkClaim",
]
