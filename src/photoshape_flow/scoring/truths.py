"""Ground truth in the stored exemplar frame: a ground-truth entry's labels cropped and resized as the
exemplar was at ingest, the majority label of a region, and each aligned part's true material and
substance (`pair_truths`), as `photoshape eval` scores the substances and inference stages."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.align.partmap import crop_square, resize_labels
from photoshape_flow.db import models as m
from photoshape_flow.evaluation.groundtruth import ItemRef, TruthEntry
from photoshape_flow.store import BlobStore


def truth_labels(truth: TruthEntry, exemplar: m.Exemplar) -> tuple[np.ndarray, list[str], list[str]]:
    """Ground-truth material and substance labels per pixel of the stored exemplar frame.

    Returns (labels (S, S) int: 0 background, i = index into the two name lists + 1, the material and
    the substance of each label); labels are the mask's parts (or materials) sorted by name.
    """
    native = truth.load_mask()
    if native.ndim == 3:
        native = native[..., 0]
    by_value = truth.pixel_truths()
    names = sorted({p.name for p in by_value.values()})
    part_of = {p.name: p for p in by_value.values()}
    lut = np.zeros(int(max(max(by_value, default=0), int(native.max(initial=0)))) + 1, np.int32)
    for value, part in by_value.items():
        lut[int(value)] = names.index(part.name) + 1
    crop = (exemplar.meta or {}).get("crop") or {"x0": 0, "y0": 0, "side": max(native.shape)}
    cropped = crop_square(lut[native.astype(np.int64)], int(crop["x0"]), int(crop["y0"]), int(crop["side"]), fill=0)
    labels = resize_labels(cropped.astype(np.int32), int(exemplar.size or cropped.shape[0]))
    return labels, [part_of[n].material for n in names], [part_of[n].substance for n in names]


def majority_label(labels: np.ndarray, mask: np.ndarray, min_fraction: float = 0.5) -> int | None:
    """The non-zero label covering most of `mask` (None when the mask is mostly ground-truth background)."""
    values = labels[mask]
    if values.size == 0:
        return None
    counts = np.bincount(values, minlength=1)
    if counts[1:].sum() < min_fraction * values.size:
        return None
    return int(np.argmax(counts[1:]) + 1)


def merge_labels(labels: np.ndarray, names: Sequence[str]) -> tuple[np.ndarray, list[str]]:
    """`truth_labels`' labels with the parts that share a name (material or substance) merged into one.

    Returns (labels: 0 background, i = index into the distinct names + 1, the distinct names sorted), so
    that `majority_label` picks the material (or substance) covering most of a mask, not the single part:
    two legs of one wood outvote a larger seat of leather.
    """
    distinct = sorted(set(names))
    lut = np.zeros(len(names) + 1, np.int32)
    for i, name in enumerate(names):
        lut[i + 1] = distinct.index(name) + 1
    return lut[labels], distinct


def _part_map(store: BlobStore, alignment: m.Alignment, size: int) -> np.ndarray:
    part_map = store.load_image(alignment.crf_blob)
    if part_map.ndim == 3:
        part_map = part_map[..., 0]
    return resize_labels(part_map, size).astype(np.int32)


def pair_truths(session: Session, store: BlobStore, pair: m.Pair, exemplar: m.Exemplar, alignment: m.Alignment,
                truth: TruthEntry) -> dict[int, tuple[str, str]]:
    """Shape part index -> the (material, substance) that part of this pair is scored against.

    With a mask: the material and the substance covering most of the part's aligned pixels (parts
    sharing a material merged first; parts mostly over background are not scored). Without one:
    the entry's part of the same name, and only when the pair's shape is the exemplar's true shape.
    """
    parts = dict(session.execute(sa.select(m.Part.index, m.Part.name).where(m.Part.shape_id == pair.shape_id)).all())
    if truth.mask is None:
        shape = session.get(m.Shape, pair.shape_id)
        if shape is None or truth.shape_ref != ItemRef(shape.source, shape.source_id):
            return {}
        return {i: (truth.parts[n].material, truth.parts[n].substance) for i, n in parts.items() if n in truth.parts}
    labels, mats, subs = truth_labels(truth, exemplar)
    mat_labels, mat_names = merge_labels(labels, mats)
    sub_labels, sub_names = merge_labels(labels, subs)
    part_map = _part_map(store, alignment, labels.shape[0])
    out = {}
    for index in parts:
        mask = part_map == index
        material, substance = majority_label(mat_labels, mask), majority_label(sub_labels, mask)
        if material is not None and substance is not None:  # both label the same pixels: None together
            out[index] = (mat_names[material - 1], sub_names[substance - 1])
    return out


