"""The ingest stage: shapes, exemplars, materials and envmaps into the database and blob store.

One function per collection, callable from the CLI and from Prefect flows alike. Each opens its own
sessions (one transaction per item), never raises for bad input (it is recorded as a `rejected`
row, or `failed` for crashes and timeouts, and listed in the returned `IngestSummary`), and is
idempotent: re-ingesting unchanged files changes nothing, changed files replace their rows' data
and invalidate what was derived from them.
"""

from __future__ import annotations

from photoshape_flow.events import MATERIAL_EVENT
from photoshape_flow.ingest.common import IngestLimits, IngestSummary, split_for
from photoshape_flow.ingest.envmaps import balance_envmap_splits, ingest_envmaps
from photoshape_flow.ingest.exemplars import delete_exemplar_dependents, ingest_exemplars
from photoshape_flow.ingest.materials import ingest_materials, render_material_previews
from photoshape_flow.ingest.shapes import delete_shape_dependents, ingest_shapes

__all__ = [
    "MATERIAL_EVENT",
    "IngestLimits",
    "IngestSummary",
    "balance_envmap_splits",
    "delete_exemplar_dependents",
    "delete_shape_dependents",
    "ingest_envmaps",
    "ingest_exemplars",
    "ingest_materials",
    "ingest_shapes",
    "render_material_previews",
    "split_for",
]
