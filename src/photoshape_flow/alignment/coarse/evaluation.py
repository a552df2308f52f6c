"""How well the reverse index finds each exemplar's true shape and pose, against demo ground truth."""

from __future__ import annotations

from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.descriptors import crop_mask
from photoshape_flow.align.viewpoints import angular_errors_deg, cameras_from_rows
from photoshape_flow.alignment.coarse.config import CoarseConfig
from photoshape_flow.alignment.coarse.reverse_index import load_reverse_index
from photoshape_flow.alignment.coarse.viewpoint_sets import config_viewpoint_set
from photoshape_flow.db import models as m
from photoshape_flow.demo.groundtruth import exemplar_records, record_field, source_keys
from photoshape_flow.evaluation.bootstrap import OBSERVATIONS
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import default_store


def evaluate_coarse_alignment(
    session: Session,
    groundtruth: Any,
    *,
    config: CoarseConfig | None = None,
    renderer: RendererProtocol | None = None,
    iou_size: int = 128,
) -> dict[str, Any]:
    """Shape recall, pose error and silhouette IoU of the reverse index against demo ground truth.

    `groundtruth` is the demo's `GroundTruth` (``demo.groundtruth.load_groundtruth``) or a mapping from
    an exemplar's file stem (its ``source_id``, or that path's stem) to a dict with the true shape's
    ``shape``/``shape_source_id``, ``in_collection`` and ``camera`` (azimuth and elevation, radians).
    Shape recall@1/@5 counts exemplars whose shape is in the collection;
    the pose error is measured at the true shape's entry when it was retrieved (median degrees,
    azimuth wrapped); the silhouette IoU renders the top-1 shape's part IDs at the retrieved camera,
    crops it like the exemplar and compares it with the exemplar's mask (``iou_nearest``: exemplars
    whose shape is not in the collection, ``iou_in_collection``: the others). Under `OBSERVATIONS`,
    each mean's values per exemplar id, for its bootstrap interval.
    """
    config = config or CoarseConfig()
    store = default_store()
    vpset = config_viewpoint_set(session, config)
    cameras = cameras_from_rows(vpset.cameras)
    index = load_reverse_index(session, config)
    exemplars = session.execute(sa.select(m.Exemplar.id, m.Exemplar.source_id, m.Exemplar.mask_blob)).all()
    by_stem: dict[str, tuple[int, str | None]] = {}
    for eid, source_id, mask_blob in exemplars:
        for key in source_keys(source_id):
            by_stem.setdefault(key, (eid, mask_blob))
    shape_ids = {src: sid for sid, src in session.execute(sa.select(m.Shape.id, m.Shape.source_id))}
    meshes = dict(session.execute(sa.select(m.Shape.id, m.Shape.mesh_blob)).all())

    hits = {1: 0, 5: 0}
    n_in = 0
    az_err: list[float] = []
    el_err: list[float] = []
    iou: dict[bool, list[float]] = {True: [], False: []}
    per_exemplar: dict[str, dict[int, list[float]]] = {
        "recall@1": {}, "recall@5": {}, "mean_iou_nearest": {}, "mean_iou_in_collection": {}}
    mesh_cache: dict[int, Any] = {}
    for stem, truth in exemplar_records(groundtruth).items():
        found = by_stem.get(str(stem))
        if found is None or found[0] not in index:
            continue
        eid, mask_blob = found
        listed = index[eid]
        retrieved = [int(s) for s in listed[:, 0]]
        true_sid = shape_ids.get(str(record_field(truth, "shape_source_id", "shape", "shape_id")))
        in_collection = true_sid is not None and bool(record_field(truth, "in_collection", default=True))
        if in_collection:
            n_in += 1
            for k in hits:
                hits[k] += int(true_sid in retrieved[:k])
                per_exemplar[f"recall@{k}"][eid] = [float(true_sid in retrieved[:k])]
            camera = record_field(truth, "camera")
            if true_sid in retrieved and camera is not None:
                view = int(listed[retrieved.index(true_sid), 1])
                daz, del_ = angular_errors_deg(
                    cameras[view].azimuth, cameras[view].elevation,
                    float(record_field(camera, "azimuth")), float(record_field(camera, "elevation")),
                )
                az_err.append(float(daz))
                el_err.append(float(del_))
        if len(retrieved) and mask_blob is not None and meshes.get(retrieved[0]):
            if renderer is None:
                renderer = default_renderer()
            sid = retrieved[0]
            if sid not in mesh_cache:
                mesh_cache[sid] = ShapeMesh.from_npz_bytes(store.read_bytes(meshes[sid]))
            ids = renderer.part_ids(mesh_cache[sid], cameras[int(listed[0, 1])], size=2 * iou_size)
            ours = crop_mask(ids > 0, iou_size)
            theirs = crop_mask(store.load_image(mask_blob), iou_size)
            union = np.logical_or(ours, theirs).sum()
            iou[in_collection].append(float(np.logical_and(ours, theirs).sum() / union) if union else 0.0)
            key = "mean_iou_in_collection" if in_collection else "mean_iou_nearest"
            per_exemplar[key][eid] = [iou[in_collection][-1]]

    def median(values: list[float]) -> float:
        return float(np.median(values)) if values else float("nan")

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else float("nan")

    return {
        "recall@1": hits[1] / n_in if n_in else float("nan"),
        "recall@5": hits[5] / n_in if n_in else float("nan"),
        "n_in_collection": float(n_in),
        "median_azimuth_error_deg": median(az_err),
        "median_elevation_error_deg": median(el_err),
        "n_pose": float(len(az_err)),
        "mean_iou_nearest": mean(iou[False]),
        "median_iou_nearest": median(iou[False]),
        "n_nearest": float(len(iou[False])),
        "mean_iou_in_collection": mean(iou[True]),
        OBSERVATIONS: per_exemplar,
    }
