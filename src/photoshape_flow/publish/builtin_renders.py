"""The shape with its own (built-in) materials at the exemplar's view: the baseline beside the photo.

Every candidate gets one, published or not, so the gallery shows photo and shape side by side on
each candidate page. Publish renders it at the PhotoShape's size for the pairs it publishes;
`run_builtin_renders` renders the waiting candidates' at thumbnail quality (`THUMBNAIL`), which is
what the candidates page shows. Rows: kind ``builtin``, key ``f"{pair_id}/exemplar"``, hashed by
the mesh, its built-in materials, the envmap, camera, size, spp and seed, not by the method, so one
render serves every method and an up-to-date one is skipped.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import sqlalchemy as sa

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.hashing import stable_hash
from photoshape_flow.pipeline.render_inputs import envmap_spec
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.publish.photoshapes import CODE_VERSION, choose_envmap, framed_views, pair_camera, render_seed
from photoshape_flow.publish.rendering import LazyRenderer, RenderCounts, render_and_record
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.vocab import STATUS_OK

log = logging.getLogger(__name__)

BUILTIN_KIND = "builtin"
THUMBNAIL = (128, 16)  # (size, spp) of a waiting candidate's render: a table thumbnail, click to enlarge


@dataclass(frozen=True)
class Lighting:
    """The studio envmap publish renders under (`choose_envmap`); all None: a constant white sky."""

    name: str | None = None
    blob: str | None = None
    id: int | None = None
    spec: Any = None


def builtin_key(pair_id: int) -> str:
    return f"{pair_id}/exemplar"


def render_builtin(url: str, store: BlobStore, renderer: Callable[[], RendererProtocol], counts: Any,
                   fail: Callable[[str], None], *, seed: int, pair_id: int, shape_id: int, mesh: Any, mesh_blob: str,
                   camera: Any, lighting: Lighting, size: int, spp: int, floor: bool = False) -> None:
    """One pair's built-in render at the exemplar's (framed) view, unless an ok row has the same hash."""
    framed = framed_views(mesh, camera, 0)[0][1]
    key = builtin_key(pair_id)
    render_seed_ = render_seed(seed, BUILTIN_KIND, key)
    params = {"camera": framed.to_dict(), "size": size, "spp": spp, "floor": floor, "seed": render_seed_,
              "envmap": lighting.name, "background": "white"}
    params_hash = stable_hash({"code": CODE_VERSION, "mesh": mesh_blob, "envmap_blob": lighting.blob,
                               "parts": [{"part": p.index, "builtin": p.builtin_material} for p in mesh.parts],
                               **params})
    with session_scope(url) as session:
        existing = session.execute(sa.select(m.Rendering.params_hash, m.Rendering.status).where(
            m.Rendering.kind == BUILTIN_KIND, m.Rendering.key == key)).one_or_none()
    if existing is not None and tuple(existing) == (params_hash, STATUS_OK):
        counts.skipped += 1
        return
    render_and_record(url, store, renderer, counts, fail, mesh=mesh, materials=[None] * len(mesh.parts),
                      camera=framed, envmap=lighting.spec, jitters=None, size=size, spp=spp, floor=floor,
                      seed=render_seed_,
                      row={"kind": BUILTIN_KIND, "key": key, "params": params, "shape_id": shape_id,
                           "pair_id": pair_id, "envmap_id": lighting.id, "params_hash": params_hash,
                           "classifier_id": None})


def run_builtin_renders(pair_ids: Sequence[int], settings: Settings | None = None, *,
                        size: int = THUMBNAIL[0], spp: int = THUMBNAIL[1],
                        renderer: RendererProtocol | None = None, progress: Progress | None = None,
                        store: BlobStore | None = None) -> RenderCounts:
    """The built-in render of each of `pair_ids` that is missing or out of date; resumable, idempotent."""
    settings = settings or get_settings()
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    counts, lazy = RenderCounts(), LazyRenderer(store, renderer)

    def fail(message: str) -> None:
        log.warning("built-in renders: %s", message)
        counts.errors.append(message)

    with session_scope(url) as session:
        row = choose_envmap(session)
        lighting = Lighting(row.name, row.blob, row.id, envmap_spec(row, store)) if row is not None else Lighting()
    for pair_id in counted(progress, "built-in renders", pair_ids):
        try:
            with session_scope(url) as session:
                pair = session.get(m.Pair, pair_id)
                shape = session.get(m.Shape, pair.shape_id)
                mesh_blob, camera = shape.mesh_blob, pair_camera(pair)
            mesh = ShapeMesh.from_npz_bytes(store.read_bytes(mesh_blob))
        except Exception as exc:  # one broken candidate must not stop the batch
            counts.failed += 1
            fail(f"pair {pair_id}: {type(exc).__name__}: {exc}")
            continue
        render_builtin(url, store, lazy, counts, fail, seed=settings.seed, pair_id=pair_id, shape_id=pair.shape_id,
                       mesh=mesh, mesh_blob=mesh_blob, camera=camera, lighting=lighting, size=size, spp=spp)
    counts.errors = counts.errors[:20]
    return counts
