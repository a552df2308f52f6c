"""PhotoShape candidates and what one is made of: the rows and blobs to render and export it.

A *candidate* is a non-excluded pair with rank-1 assignments for a method (the `photoshape_candidate`
view); `candidate_method_keys` lists them and `load_photoshape` reads one into the inputs of the
renderer and the exporters (mesh, material specs, UV transforms, the exemplar's camera, the
`assignment.json` document and the fingerprint its renders are hashed by).

The envmap is chosen deterministically (`choose_envmap`): enabled and ok rows, preferring
``meta.studio`` true, then a name containing "studio", then the lowest id; None (a constant white
sky) when there is none.

Assignment UV transforms: ``Assignment.params["uv"] = {"scale", "rotation", "offset"}`` when the
inference stage recorded one, otherwise none (the texture-scale formula alone). A rank-1 row's
``refinement`` (`fit.refine`: tint, roughness scale, UV scale and rotation) goes onto its material
spec, so renders and exports show the refined look; `PhotoShape.unrefined` keeps the specs without
it for the gallery's before/after render (view `UNREFINED_VIEW`).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import zoom_to_fit
from photoshape_flow.db import models as m
from photoshape_flow.export.assignment import PartAssignment, Provenance, assignment_document
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.hashing import stable_hash
from photoshape_flow.method_keys import is_method_name
from photoshape_flow.pipeline.render_inputs import envmap_spec, material_spec
from photoshape_flow.profiles import DEFAULT_PUBLISH_METHOD
from photoshape_flow.render import Camera, Refinement, UVTransform
from photoshape_flow.store import BlobStore
from photoshape_flow.vocab import STATUS_OK

CODE_VERSION = "publish-v1"  # part of every PhotoShape's fingerprint: bump it to redo renders and exports
# elevation (rad), distance, horizontal fov (deg): the unit cube's bounding sphere (r = 0.87) fits the frame
TURNTABLE_CAMERA = (math.radians(20.0), 2.6, 40.0)
FRAME_MARGIN = 0.08  # fraction of the frame left around the shape in PhotoShape renders
EXEMPLAR_VIEW = "exemplar"
UNREFINED_VIEW = "exemplar-unrefined"  # the exemplar view with the winners before refinement


def render_seed(global_seed: int, kind: str, key: str) -> int:
    """A render seed (31 bits, what Mitsuba takes) from the global seed and the render's kind and key."""
    return int.from_bytes(hashlib.sha256(f"{global_seed}/{kind}/{key}".encode()).digest()[:4], "little") >> 1


def render_key(pair_id: int, method_key: str, view: str) -> str:
    """The `Rendering.key` of one PhotoShape view (kind ``photoshape``)."""
    return f"{pair_id}/{method_key}/{view}"


def candidate_method_keys(session: Session, method: str | None, pair_ids: Sequence[int] | None = None
                          ) -> list[tuple[int, str]]:
    """(pair_id, method_key) of every non-excluded candidate with rank-1 rows for `method`.

    `method` is a method name (``classifier`` takes each pair's newest classifier) or an exact
    method key (``classifier:3``, ``builtin``).
    """
    method = method or DEFAULT_PUBLISH_METHOD
    query = (
        sa.select(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.method,
                  sa.func.max(m.Assignment.classifier_id))
        .join(m.Pair, m.Pair.id == m.Assignment.pair_id)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .where(m.Assignment.rank == 1, ~m.Pair.exclude, ~m.Shape.exclude, ~m.Exemplar.exclude)
        .group_by(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.method)
        .order_by(m.Assignment.pair_id)
    )
    if pair_ids is not None:
        query = query.where(m.Assignment.pair_id.in_(list(pair_ids)))
    best: dict[int, tuple[int, str]] = {}
    for pair_id, method_key, row_method, classifier_id in session.execute(query):
        if method_key == method:
            best[pair_id] = (1 << 62, method_key)  # an exact key always wins
        elif row_method == method and is_method_name(method):
            rank = classifier_id or 0
            if pair_id not in best or best[pair_id][0] < rank:
                best[pair_id] = (rank, method_key)
    return [(pair_id, key) for pair_id, (_, key) in sorted(best.items())]


def assignment_set_keys(session: Session, pairs: Sequence[tuple[int, str]]) -> dict[tuple[int, str], str]:
    """(pair_id, method_key) -> a stable key of the rank-1 assignment set it names.

    The key changes whenever what a PhotoShape shows changes (another classifier, material, substance or
    UV transform on any part), so "already published" and a grade can be keyed by what was shown rather
    than by the pair alone. Pairs without rank-1 rows are absent.
    """
    wanted = set(pairs)
    if not wanted:
        return {}
    rows: dict[tuple[int, str], list[list[Any]]] = {}
    refinements = {  # refined looks are other sets; unrefined rows keep the keys they had
        (pair_id, method_key, part_id): refinement for pair_id, method_key, part_id, refinement in session.execute(
            sa.select(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.part_id, m.Assignment.refinement)
            .where(m.Assignment.rank == 1, m.Assignment.refinement.is_not(None),
                   m.Assignment.pair_id.in_(sorted({p for p, _ in wanted}))))
    }
    query = (
        sa.select(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.part_id, m.Assignment.material_id,
                  m.Assignment.substance, m.Assignment.classifier_id, m.Assignment.params)
        .where(m.Assignment.rank == 1, m.Assignment.pair_id.in_(sorted({p for p, _ in wanted})))
        .order_by(m.Assignment.pair_id, m.Assignment.method_key, m.Assignment.part_id)
    )
    for pair_id, method_key, part_id, material_id, substance, classifier_id, params in session.execute(query):
        if (pair_id, method_key) in wanted:
            rows.setdefault((pair_id, method_key), []).append(
                [part_id, material_id, substance, classifier_id, (params or {}).get("uv"),
                 *([refinements[(pair_id, method_key, part_id)]] if (pair_id, method_key, part_id) in refinements
                   else [])])
    return {key: stable_hash({"method_key": key[1], "parts": parts}) for key, parts in rows.items()}


def choose_envmap(session: Session) -> m.Envmap | None:
    """The studio envmap every PhotoShape render uses (see the module docstring)."""
    rows = session.execute(
        sa.select(m.Envmap).where(m.Envmap.enabled, m.Envmap.status == STATUS_OK, m.Envmap.blob.is_not(None))
        .order_by(m.Envmap.id)
    ).scalars().all()
    if not rows:
        return None
    return min(rows, key=lambda e: (not (e.meta or {}).get("studio"), "studio" not in e.name.lower(), e.id))


def provenance(role: str, row: Any) -> Provenance:
    return Provenance(role=role, id=row.id, name=getattr(row, "name", None) or getattr(row, "source_id", None),
                      source=getattr(row, "source", None), license=row.license, attribution=row.attribution,
                      source_url=row.source_url)


def _uv_transform(params: dict[str, Any] | None) -> Any:
    uv = (params or {}).get("uv")
    if not isinstance(uv, dict):
        return None
    offset = uv.get("offset", (0.0, 0.0))
    return UVTransform(float(uv.get("scale", 1.0)), float(uv.get("rotation", 0.0)),
                       (float(offset[0]), float(offset[1])))


@dataclass
class PhotoShape:
    """Everything needed to render and export one candidate with one method."""

    pair_id: int
    method_key: str
    shape_id: int
    exemplar_id: int
    classifier_id: int | None
    mesh: Any
    materials: list[Any]  # MaterialSpec | None (built-in) per part
    uv_transforms: list[Any]  # UVTransform | None per part
    camera: Any  # the exemplar's view
    document: dict[str, Any]  # assignment.json
    fingerprint: dict[str, Any]  # inputs that the renders depend on (for params_hash)
    envmap: Any = None  # EnvmapSpec
    envmap_id: int | None = None
    exemplar_blob: str | None = None
    material_rows: dict[int, Any] = field(default_factory=dict)
    unrefined: list[Any] | None = None  # `materials` without their refinements; None when no part is refined


def load_photoshape(session: Session, store: BlobStore, pair_id: int, method_key: str,
                    envmap: m.Envmap | None = None) -> PhotoShape:
    """Read a candidate's rows and blobs into render/export inputs; a one-line error when incomplete."""
    pair = session.get(m.Pair, pair_id)
    if pair is None:
        raise ValueError(f"pair {pair_id}: no such pair")
    shape, exemplar = session.get(m.Shape, pair.shape_id), session.get(m.Exemplar, pair.exemplar_id)
    if shape is None or exemplar is None or not shape.mesh_blob:
        raise ValueError(f"pair {pair_id}: shape or exemplar missing, or the shape has no mesh")
    mesh = ShapeMesh.from_npz_bytes(store.read_bytes(shape.mesh_blob))
    parts = {p.index: p for p in session.execute(sa.select(m.Part).where(m.Part.shape_id == shape.id)).scalars()}
    rows = {
        a.part_id: a for a in session.execute(
            sa.select(m.Assignment).where(m.Assignment.pair_id == pair_id, m.Assignment.method_key == method_key,
                                          m.Assignment.rank == 1)
        ).scalars()
    }
    if not rows:
        raise ValueError(f"pair {pair_id}: no rank-1 assignments for {method_key}")
    material_ids = sorted({a.material_id for a in rows.values() if a.material_id is not None})
    material_rows = {r.id: r for r in session.execute(sa.select(m.Material).where(m.Material.id.in_(material_ids)))
                     .scalars()}
    specs: dict[int, Any] = {mid: material_spec(row, store) for mid, row in material_rows.items()}
    materials, jitters, assigned, fingerprint_parts, unrefined = [], [], [], [], []
    classifier_id = None
    for part_mesh in mesh.parts:
        row_part = parts.get(part_mesh.index)
        a = rows.get(row_part.id) if row_part is not None else None
        spec = specs.get(a.material_id) if a is not None and a.material_id is not None else None
        jitter = _uv_transform(a.params) if a is not None and spec is not None else None
        refinement = a.refinement if a is not None and spec is not None and a.refinement else None
        unrefined.append(spec)
        if refinement is not None:
            spec = replace(spec, refinement=Refinement.from_dict(refinement))
        materials.append(spec)
        jitters.append(jitter)
        classifier_id = classifier_id or (a.classifier_id if a is not None else None)
        mat = material_rows.get(a.material_id) if a is not None and a.material_id is not None else None
        assigned.append(PartAssignment(
            part_index=part_mesh.index, part_name=part_mesh.name,
            material_id=mat.id if mat else None, material_name=mat.name if mat else None,
            substance=(a.substance if a is not None else None) or (mat.substance if mat else None),
            score=a.score if a is not None else None, unobserved=bool(a.unobserved) if a is not None else False,
            uv_density=float(part_mesh.uv_density), material_scale=spec.scale if spec is not None else None,
            uv_transform=jitter.to_dict() if jitter is not None else None,
            extra={"refinement": refinement} if refinement is not None else {},
        ))
        fingerprint_parts.append({
            "part": part_mesh.index,
            "material": None if mat is None else [mat.id, mat.params_hash, mat.maps, mat.params, mat.default_scale],
            "builtin": part_mesh.builtin_material if spec is None else None,
            "uv": jitter.to_dict() if jitter is not None else None,
            **({"refinement": refinement} if refinement is not None else {}),
        })
    camera = pair_camera(pair)
    lighting = envmap_spec(envmap, store) if envmap is not None else None
    document = assignment_document(
        pair_id=pair_id, method_key=method_key,
        shape=provenance("shape", shape), exemplar=provenance("exemplar", exemplar), parts=assigned,
        materials=[provenance("material", material_rows[mid]) for mid in material_ids],
        envmap=provenance("envmap", envmap) if envmap is not None else None,
        camera=camera.to_dict(),
        extra={"hog_distance": pair.distance, "generator": CODE_VERSION},
    )
    fingerprint = {
        "code": CODE_VERSION, "mesh": shape.mesh_blob, "parts": fingerprint_parts,
        "envmap": None if envmap is None else envmap.blob,
    }
    return PhotoShape(
        pair_id=pair_id, method_key=method_key, shape_id=shape.id, exemplar_id=exemplar.id,
        classifier_id=classifier_id, mesh=mesh, materials=materials, uv_transforms=jitters, camera=camera,
        document=document, fingerprint=fingerprint, envmap=lighting,
        envmap_id=envmap.id if envmap is not None else None, exemplar_blob=exemplar.image_blob,
        material_rows=material_rows, unrefined=unrefined if unrefined != materials else None,
    )


def pair_camera(pair: m.Pair) -> Camera:
    """The exemplar's view: the camera coarse alignment matched the pair with."""
    return Camera(float(pair.azimuth), float(pair.elevation), float(pair.camera_distance), float(pair.fov))


def framed_views(mesh: Any, camera: Any, views: int) -> list[tuple[str, Any]]:
    """`views_of`, each view framed like a product photo: the fov narrowed until the shape fills it.

    Publish renders these cameras and the exports write the exemplar one, so a downloaded scene
    shows what the gallery shows.
    """
    return [(view, zoom_to_fit(mesh, cam, margin=FRAME_MARGIN)) for view, cam in views_of(camera, views)]


def exemplar_render(item: PhotoShape, global_seed: int) -> tuple[Any, int]:
    """(camera, seed) of a PhotoShape's exemplar-view render: what its exports must reproduce."""
    camera = framed_views(item.mesh, item.camera, 0)[0][1]
    return camera, render_seed(global_seed, "photoshape", render_key(item.pair_id, item.method_key, EXEMPLAR_VIEW))


def views_of(camera: Any, views: int) -> list[tuple[str, Any]]:
    """The exemplar's view, then a canonical turntable of `views` azimuths starting at the front (+z).

    The turntable is the same for every PhotoShape (elevation, distance and fov fixed by
    `TURNTABLE_CAMERA`), so the gallery compares shapes from identical angles and no turntable view
    repeats the exemplar's own.
    """
    elevation, distance, fov = TURNTABLE_CAMERA
    turntable = [
        (f"turntable-{i:02d}", camera.replace(azimuth=2.0 * math.pi * i / views, elevation=elevation,
                                              distance=distance, fov=fov))
        for i in range(max(0, views))
    ]
    return [(EXEMPLAR_VIEW, camera), *turntable]
