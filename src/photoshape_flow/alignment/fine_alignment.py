"""Fine alignment stage (section 4.2): for every pair, p_coarse -> p_flow -> p_crf, as Alignment rows.

Per pending pair: render the shape's exact part IDs at the pair's camera, crop them like the
exemplar (`align.partmap`), warp them onto the exemplar's silhouette and clean them with the dense
CRF (`align.fine`), store the three part maps as 16-bit PNG blobs, then upsert the `Alignment`
row (pair_id, method) with the parameters, timing and silhouette IoU after each step. A pair is
pending when it has no row for the method or its row's params_hash differs from the hash of the
current inputs (mesh, exemplar image and mask, camera) and settings; failed rows are retried only
when asked. A failure is recorded on the row (status `failed`, one-line error) and the batch goes on.

`evaluate_fine_alignment` scores stored maps against the demo ground truth: part-label accuracy
after each step for pairs whose shape is the exemplar's own (written to the row's accuracy_*
columns), silhouette IoU for the others.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.crf import pydensecrf_available
from photoshape_flow.align.fine import FineParams, align_pair, part_label_accuracy
from photoshape_flow.align.partmap import crop_square, exemplar_at, render_coarse_part_map, resize_labels, square_box
from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.db.upsert import upsert
from photoshape_flow.demo.groundtruth import exemplar_records, record_field, record_for_source, record_mask
from photoshape_flow.evaluation.bootstrap import OBSERVATIONS
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.hashing import stable_hash
from photoshape_flow.pipeline.errors import error_line
from photoshape_flow.progress_sink import Progress, counted
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store

log = logging.getLogger(__name__)

STAGE = "fine-alignment"
DEFAULT_METHOD = "flow-crf"
UNMATCHED = np.uint16(65535)  # ground-truth part with no same-named part in the shape


def alignment_hash(params: FineParams, method: str, item: Mapping[str, Any]) -> str:
    """params_hash of an Alignment row: settings plus every input the maps depend on."""
    payload = {
        "stage": STAGE,
        "method": method,
        "params": params.to_dict(),
        "mesh": item["mesh_blob"],
        "image": item["image_blob"],
        "mask": item["mask_blob"],
        "camera": [round(float(item[k]), 9) for k in ("azimuth", "elevation", "camera_distance", "fov")],
    }
    return stable_hash(payload)


def _candidates(session: Session, pair_ids: Iterable[int] | None, method: str) -> list[dict[str, Any]]:
    """Active pairs (not excluded, shape and exemplar usable) with their inputs and current row."""
    query = (
        sa.select(
            m.Pair.id.label("pair_id"), m.Pair.shape_id, m.Pair.exemplar_id, m.Pair.azimuth, m.Pair.elevation,
            m.Pair.camera_distance, m.Pair.fov, m.Shape.mesh_blob, m.Exemplar.image_blob, m.Exemplar.mask_blob,
            m.Alignment.params_hash.label("row_hash"), m.Alignment.status.label("row_status"),
        )
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .outerjoin(m.Alignment, sa.and_(m.Alignment.pair_id == m.Pair.id, m.Alignment.method == method))
        .where(~m.Pair.exclude, ~m.Shape.exclude, ~m.Exemplar.exclude)
        .where(m.Shape.status == "ok", m.Exemplar.status == "ok")
        .order_by(m.Pair.shape_id, m.Pair.id)
    )
    if pair_ids is not None:
        query = query.where(m.Pair.id.in_([int(i) for i in pair_ids]))
    return [dict(row._mapping) for row in session.execute(query)]


def expected_hashes(session: Session, pair_ids: Iterable[int], params: FineParams,
                    method: str = DEFAULT_METHOD) -> dict[int, str]:
    """pair id -> the params_hash its Alignment row must have to be up to date (active pairs only)."""
    items = _candidates(session, pair_ids, method)
    return {int(item["pair_id"]): alignment_hash(params, method, item) for item in items}


class _MeshCache:
    """A few recently used meshes, so consecutive pairs of one shape reuse its loaded scene."""

    def __init__(self, store: BlobStore, size: int = 4):
        self.store = store
        self.size = size
        self.items: OrderedDict[str, Any] = OrderedDict()

    def get(self, ref: str) -> Any:
        if ref in self.items:
            self.items.move_to_end(ref)
            return self.items[ref]
        mesh = ShapeMesh.from_npz_bytes(self.store.read_bytes(ref))
        self.items[ref] = mesh
        while len(self.items) > self.size:
            self.items.popitem(last=False)
        return mesh


def _align_item(
    item: Mapping[str, Any], params: FineParams, store: BlobStore, renderer: RendererProtocol, meshes: _MeshCache
) -> dict[str, Any]:
    """Compute and store one pair's maps; returns the Alignment columns (raises on bad input)."""
    for column in ("mesh_blob", "image_blob", "mask_blob"):
        if not item[column]:
            raise ValueError(f"pair {item['pair_id']}: {column} is missing")
    start = time.perf_counter()
    shape = meshes.get(item["mesh_blob"])
    rgb, fg = exemplar_at(store.load_image(item["image_blob"]), store.load_image(item["mask_blob"]), params.size)
    box = square_box(fg)
    if box is None:
        raise ValueError(f"exemplar {item['exemplar_id']}: the mask is empty")
    camera = Camera(*(float(item[k]) for k in ("azimuth", "elevation", "camera_distance", "fov")))
    coarse = render_coarse_part_map(renderer, shape, camera, params.size, target_box=box)
    result = align_pair(coarse, rgb, fg, params)
    seconds = time.perf_counter() - start
    refs = {name: store.put_image(getattr(result, name).astype(np.uint16), "png") for name in ("coarse", "flow", "crf")}
    details = params.to_dict()
    details["target_box"] = list(box)
    details["crf_backend"] = params.crf.backend if params.crf.backend != "auto" else (
        "pydensecrf" if pydensecrf_available() else "fallback"
    )
    return {
        "coarse_blob": refs["coarse"],
        "flow_blob": refs["flow"],
        "crf_blob": refs["crf"],
        "iou_coarse": result.iou_coarse,
        "iou_flow": result.iou_flow,
        "iou_crf": result.iou_crf,
        "accuracy_coarse": None,
        "accuracy_flow": None,
        "accuracy_crf": None,
        "seconds": round(seconds, 4),
        "params": details,
        "status": "ok",
        "error": None,
    }


def _failed_columns(error: str, params: FineParams) -> dict[str, Any]:
    return {
        "coarse_blob": None, "flow_blob": None, "crf_blob": None,
        "iou_coarse": None, "iou_flow": None, "iou_crf": None,
        "accuracy_coarse": None, "accuracy_flow": None, "accuracy_crf": None,
        "seconds": None, "params": params.to_dict(), "status": "failed", "error": error,
    }


def run_fine_alignment(
    pair_ids: Iterable[int] | None = None,
    settings: Settings | None = None,
    method: str = DEFAULT_METHOD,
    *,
    params: FineParams | None = None,
    renderer: RendererProtocol | None = None,
    limit: int | None = None,
    retry_failed: bool = False,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> dict[str, Any]:
    """Fine-align pending pairs (all active pairs, or those in `pair_ids`); returns a summary.

    `method` names the Alignment rows (unique with the pair); `params` are its settings (default
    `FineParams()`); `renderer` anything with `part_ids(shape, camera, size)` (default: Mitsuba, built
    when a pair is pending); `store` the blob store (default: the one `settings` configure).
    """
    settings = settings or get_settings()
    params = params or FineParams()
    store = store if store is not None else default_store(settings)
    url = settings.resolved_database_url
    start = time.perf_counter()
    with session_scope(url) as session:
        candidates = _candidates(session, None if pair_ids is None else list(pair_ids), method)
    pending = []
    for item in candidates:
        item["hash"] = alignment_hash(params, method, item)
        stale = item["row_hash"] != item["hash"]
        if item["row_hash"] is None or stale or (retry_failed and item["row_status"] != "ok"):
            pending.append(item)
    if limit is not None:
        pending = pending[: max(int(limit), 0)]
    summary: dict[str, Any] = {
        "stage": STAGE, "method": method, "candidates": len(candidates),
        "up_to_date": len(candidates) - len(pending), "aligned": 0, "failed": 0, "failures": [],
    }
    if pending and renderer is None:
        renderer = default_renderer(store)
    meshes = _MeshCache(store)
    ious: dict[str, list[float]] = {"coarse": [], "flow": [], "crf": []}
    seconds: list[float] = []
    for item in counted(progress, "fine-alignment pairs", pending):
        try:
            columns = _align_item(item, params, store, renderer, meshes)
        except Exception as exc:  # one bad pair must not stop the batch
            error = error_line(exc)
            log.warning("fine alignment of pair %s failed: %s", item["pair_id"], error)
            columns = _failed_columns(error, params)
            summary["failed"] += 1
            summary["failures"].append({"pair_id": item["pair_id"], "error": error})
        else:
            summary["aligned"] += 1
            seconds.append(columns["seconds"])
            for name in ious:
                ious[name].append(columns[f"iou_{name}"])
        row = {"pair_id": item["pair_id"], "method": method, "params_hash": item["hash"], **columns}
        with session_scope(url) as session:
            upsert(session, m.Alignment, row, key=["pair_id", "method"])
    for name, values in ious.items():
        summary[f"mean_iou_{name}"] = round(float(np.mean(values)), 4) if values else None
    summary["seconds_per_pair"] = round(float(np.mean(seconds)), 4) if seconds else None
    summary["seconds"] = round(time.perf_counter() - start, 3)
    log.info("fine alignment: %s", {k: v for k, v in summary.items() if k != "failures"})
    return summary


# -- evaluation against ground truth --------------------------------------------------------------


def truth_in_stored_frame(
    native_mask: np.ndarray, crop: Mapping[str, Any], part_names: Mapping[int, str], parts_by_name: Mapping[str, int],
    size: int,
) -> np.ndarray:
    """A native-frame ground-truth part mask in the stored exemplar frame at `size`, as shape part indices.

    The stored crop is the native square (x0, y0, side) (white / background where it leaves the
    photo); mask values are translated to the shape's part index through the part names, and a
    name the shape lacks becomes `UNMATCHED` (foreground that no prediction can get right).
    """
    mask = np.asarray(native_mask)
    if mask.ndim == 3:
        mask = mask[..., 0]
    cropped = crop_square(mask, int(crop["x0"]), int(crop["y0"]), int(crop["side"]), fill=0)
    lut = np.full(int(max(int(mask.max(initial=0)), max(part_names, default=0))) + 1, UNMATCHED, np.uint16)
    lut[0] = 0
    for value, name in part_names.items():
        lut[int(value)] = parts_by_name.get(name, UNMATCHED)
    return resize_labels(lut[cropped.astype(np.int64)], size)


def evaluate_fine_alignment(
    session: Session, groundtruth: Any, *, method: str = DEFAULT_METHOD, settings: Settings | None = None
) -> dict[str, Any]:
    """Accuracy after coarse, flow and CRF on demo pairs; writes accuracy_* on their Alignment rows.

    `groundtruth` is `demo.groundtruth.load_groundtruth(...)` (or a mapping stem -> record with
    ``shape``, ``part_names``, ``mask``). Pairs whose shape's source_id is the exemplar's true shape
    get part-label accuracy (over ground-truth foreground, parts matched by name; also, as a
    diagnostic, over the part of it inside the exemplar's ingest mask); the others get silhouette
    IoU. Means are over pairs.
    """
    settings = settings or get_settings()
    store = default_store(settings)
    truths = exemplar_records(groundtruth)
    root = getattr(groundtruth, "root", None)
    rows = session.execute(
        sa.select(m.Alignment, m.Exemplar, m.Shape)
        .join(m.Pair, m.Pair.id == m.Alignment.pair_id)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .join(m.Shape, m.Shape.id == m.Pair.shape_id)
        .where(m.Alignment.method == method, m.Alignment.status == "ok")
    ).all()
    accuracy: dict[str, list[float]] = {"coarse": [], "flow": [], "crf": []}
    in_mask: dict[str, list[float]] = {"coarse": [], "flow": [], "crf": []}
    iou_other: dict[str, list[float]] = {"coarse": [], "flow": [], "crf": []}
    per_exemplar: dict[str, dict[int, list[float]]] = {f"accuracy_{name}": {} for name in accuracy}
    skipped = 0
    for alignment, exemplar, shape in rows:
        entry = record_for_source(truths, exemplar.source_id)
        if entry is None:
            continue
        exact = str(record_field(entry, "shape")) == shape.source_id and bool(
            record_field(entry, "in_collection", default=True)
        )
        if not exact:
            for name in iou_other:
                value = getattr(alignment, f"iou_{name}")
                if value is not None:
                    iou_other[name].append(float(value))
            continue
        crop = (exemplar.meta or {}).get("crop")
        if not crop or not alignment.crf_blob:
            skipped += 1
            continue
        maps = {name: store.load_image(getattr(alignment, f"{name}_blob")) for name in ("coarse", "flow", "crf")}
        size = maps["crf"].shape[0]
        parts_by_name = {p.name: int(p.index) for p in shape.parts}
        part_names = {int(k): str(v) for k, v in (record_field(entry, "part_names") or {}).items()}
        truth = truth_in_stored_frame(record_mask(entry, root), crop, part_names, parts_by_name, size)
        scores = {name: part_label_accuracy(maps[name], truth) for name in maps}
        if any(np.isnan(v) for v in scores.values()):
            skipped += 1
            continue
        for name, value in scores.items():
            accuracy[name].append(value)
            per_exemplar[f"accuracy_{name}"].setdefault(exemplar.id, []).append(float(value))
            setattr(alignment, f"accuracy_{name}", float(value))
        if exemplar.mask_blob:  # diagnostic: the same inside the exemplar's (ingest) mask only
            _, fg = exemplar_at(store.load_image(exemplar.image_blob), store.load_image(exemplar.mask_blob), size)
            masked = np.where(fg, truth, 0).astype(np.uint16)
            if masked.any():
                for name in maps:
                    in_mask[name].append(part_label_accuracy(maps[name], masked))
    session.flush()

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else float("nan")

    result: dict[str, Any] = {"n_exact": len(accuracy["crf"]), "n_other": len(iou_other["crf"]), "n_skipped": skipped}
    for name in ("coarse", "flow", "crf"):
        result[f"accuracy_{name}"] = mean(accuracy[name])
    for name in ("coarse", "flow", "crf"):
        result[f"accuracy_in_mask_{name}"] = mean(in_mask[name])
    for name in ("coarse", "flow", "crf"):
        result[f"iou_other_{name}"] = mean(iou_other[name])
    result["flow_improves"] = bool(result["accuracy_flow"] > result["accuracy_coarse"]) if accuracy["crf"] else None
    result["crf_improves"] = bool(result["accuracy_crf"] > result["accuracy_flow"]) if accuracy["crf"] else None
    result[OBSERVATIONS] = per_exemplar
    return result


__all__ = [
    "DEFAULT_METHOD",
    "STAGE",
    "alignment_hash",
    "evaluate_fine_alignment",
    "run_fine_alignment",
    "truth_in_stored_frame",
]
