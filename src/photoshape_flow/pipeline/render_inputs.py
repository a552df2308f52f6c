"""Render specs from database rows: what every stage that renders a stored material or envmap hands
the renderer (training renders, fit, publish, the re-render evaluation), built in one place so they
all render a row the same way."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from photoshape_flow.db import models as m
from photoshape_flow.render import EnvmapSpec, MaterialSpec
from photoshape_flow.render.specs import CHANNELS
from photoshape_flow.store import BlobStore


def material_spec(row: m.Material, store: BlobStore) -> Any:
    """A render `MaterialSpec` from a Material row (maps resolved to blob paths)."""
    maps: dict[str, Path] = {ch: store.resolve(ref) for ch, ref in (row.maps or {}).items() if ch in CHANNELS and ref}
    return MaterialSpec(
        name=row.name, substance=row.substance, maps=maps, params=dict(row.params or {}), scale=row.default_scale
    )


def envmap_spec(row: m.Envmap, store: BlobStore) -> Any:
    """A render `EnvmapSpec` from an Envmap row (its HDR image resolved to a blob path)."""
    return EnvmapSpec(path=store.resolve(row.blob))
