"""Ground-truth entries matched to what the database holds: exemplar ids, true shapes, parts, materials.

`evaluation.groundtruth` checks an entry's shape; this module checks its names. An entry whose
exemplar is not ingested, whose shape is unknown (and not declared ``"in_collection": false``), whose
materials or substances are unknown, or which has no mask and part names that differ from the true
shape's (names are then the only way to score a part) gets one message listing every reason and
is left out; the others are scored. With a mask the pixels say which part is which, so a shape
segmented differently from the photo's labels is fine.

Source ids are matched like `evaluation.groundtruth.source_keys`: the exact id first, then the file name
and the stem, so a file written for stems keeps working after ids became relative paths.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import sqlalchemy as sa
from sqlalchemy.orm import Session

from photoshape_flow.db import models as m
from photoshape_flow.evaluation.groundtruth import (
    GroundTruthFile,
    ItemRef,
    MaskTruth,
    TruthEntry,
    read_part_mask,
    source_keys,
)
from photoshape_flow.vocab import SUBSTANCES


@dataclass(frozen=True)
class MatchedTruth:
    """exemplar id -> its entry (shape_ref the database's shape, in_collection decided), and why others
    were left out."""

    truths: dict[int, TruthEntry]
    problems: tuple[str, ...]
    source_ids: dict[int, str]  # exemplar id -> its ingested source id

    def by_source_id(self) -> dict[str, TruthEntry]:
        """The mapping the coarse and fine alignment evaluators read (keyed by ingested source id)."""
        return {self.source_ids[eid]: entry for eid, entry in self.truths.items()}


class _RefIndex:
    """Rows (id, source, source_id) found by an ItemRef: exact source id first, then its name or stem."""

    def __init__(self, rows: Iterable[tuple[int, str | None, str]]):
        self.exact: dict[str, list[tuple[int, str | None, str]]] = defaultdict(list)
        self.loose: dict[str, list[tuple[int, str | None, str]]] = defaultdict(list)
        for row in rows:
            self.exact[row[2]].append(row)
            for key in set(source_keys(row[2])[1:]) - {row[2]}:
                self.loose[key].append(row)

    def find(self, ref: ItemRef, source: str | None = None) -> list[tuple[int, str | None, str]]:
        wanted = ref.source if ref.source is not None else source
        for table in (self.exact, self.loose):
            for key in source_keys(ref.source_id):
                hits = [row for row in table.get(key, []) if wanted is None or row[1] == wanted]
                if hits:
                    return sorted(set(hits))
        return []


def _describe(hits: list[tuple[int, str | None, str]]) -> str:
    return ", ".join(f"{s}/{sid}" for _, s, sid in hits[:3]) + (" ..." if len(hits) > 3 else "")


def match_groundtruth(session: Session, gt: GroundTruthFile, source: str | None = None) -> MatchedTruth:
    """Match every entry (of `source` only, when given) to the database; see the module docstring."""
    exemplars = _RefIndex(session.execute(
        sa.select(m.Exemplar.id, m.Exemplar.source, m.Exemplar.source_id).where(m.Exemplar.status == "ok")).all())
    native = {eid: (w, h) for eid, w, h in session.execute(
        sa.select(m.Exemplar.id, m.Exemplar.native_width, m.Exemplar.native_height))}
    shapes = _RefIndex(session.execute(
        sa.select(m.Shape.id, m.Shape.source, m.Shape.source_id).where(m.Shape.status == "ok")).all())
    shape_parts: dict[int, set[str]] = defaultdict(set)
    for shape_id, name in session.execute(sa.select(m.Part.shape_id, m.Part.name)):
        shape_parts[shape_id].add(name)
    substances = dict(session.execute(sa.select(m.Material.name, m.Material.substance)).all())

    truths: dict[int, TruthEntry] = {}
    source_ids: dict[int, str] = {}
    problems: list[str] = list(gt.problems)
    for entry in gt.entries:
        if source is not None and entry.exemplar.source not in (None, source):
            continue  # another source's photo: not asked for, not an error
        reasons: list[str] = []
        found = exemplars.find(entry.exemplar, source)
        if not found:
            reasons.append(f"exemplar {entry.exemplar} is not ingested (or not ok)")
        elif len(found) > 1:
            reasons.append(f"exemplar {entry.exemplar} matches {_describe(found)}: give its source")
        elif found[0][0] in truths:
            reasons.append(f"exemplar {found[0][1]}/{found[0][2]} already has an entry")
        resolved, shape_reasons = _resolve_shape(entry, shapes, shape_parts)
        reasons += shape_reasons
        reasons += _material_reasons(entry, substances)
        if entry.mask is not None:
            reasons += _mask_reasons(entry.mask, native.get(found[0][0]) if len(found) == 1 else None)
        if reasons:
            problems.append(f"{entry.label}: {'; '.join(reasons)}; skipped")
            continue
        if entry.mask is not None and entry.mask.kind == "material":
            resolved = dataclasses.replace(resolved, material_substances={
                name: substances[name] for name in entry.mask.values.values()})
        truths[found[0][0]] = resolved
        source_ids[found[0][0]] = found[0][2]
    return MatchedTruth(truths, tuple(problems), source_ids)


def _resolve_shape(entry: TruthEntry, shapes: _RefIndex, shape_parts: dict[int, set[str]]
                   ) -> tuple[TruthEntry, list[str]]:
    """The entry with its shape named as the database names it and its membership decided, and what is
    wrong with its shape (unknown, ambiguous, or parts that differ when there is no mask)."""
    found = shapes.find(entry.shape_ref)
    if len(found) > 1:
        return entry, [f"shape {entry.shape_ref} matches {_describe(found)}: give its source"]
    if not found:
        if entry.in_collection is False:  # deliberately outside the collection (retrieval's nearest-shape case)
            return entry, []
        return entry, [f"shape {entry.shape_ref} is not ingested (say \"in_collection\": false if that is meant)"]
    shape_id, shape_source, shape_source_id = found[0]
    reasons = []
    if entry.mask is None:  # names are then the only link between the truth and the shape's parts
        reasons = _part_name_reasons(entry, f"{shape_source}/{shape_source_id}", shape_parts[shape_id])
    resolved = dataclasses.replace(entry, shape_ref=ItemRef(shape_source, shape_source_id),
                                   in_collection=True if entry.in_collection is None else entry.in_collection)
    return resolved, reasons


def _mask_reasons(mask: MaskTruth, photo_size: tuple[int | None, int | None] | None) -> list[str]:
    """A mask that is missing, unreadable, or not in the photo's own frame (its size as ingested)."""
    if not Path(mask.path).is_file():
        return [f"mask {mask.path} not found"]
    try:
        height, width = read_part_mask(mask.path).shape[:2]
    except FileNotFoundError:
        return [f"mask {mask.path} is not a readable image"]
    if photo_size is not None and None not in photo_size and (width, height) != photo_size:
        return [f"mask {mask.path} is {width}x{height} but the photo is {photo_size[0]}x{photo_size[1]}"]
    return []


def _part_name_reasons(entry: TruthEntry, shape: str, on_shape: set[str]) -> list[str]:
    """Part names of a mask-less entry that the true shape lacks, and shape parts it does not give."""
    unknown, missing = sorted(set(entry.parts) - on_shape), sorted(on_shape - set(entry.parts))
    reasons = []
    if unknown:
        reasons.append(f"parts not on shape {shape}: {', '.join(unknown)}")
    if missing:
        reasons.append(f"missing parts of shape {shape}: {', '.join(missing)}")
    return reasons


def _material_reasons(entry: TruthEntry, substances: dict[str, str]) -> list[str]:
    """Unknown material and substance names of an entry (parts and a material mask's values)."""
    named = {p.material for p in entry.parts.values()}
    if entry.mask is not None and entry.mask.kind == "material":
        named |= set(entry.mask.values.values())
    reasons = []
    unknown = sorted(named - set(substances))
    if unknown:
        reasons.append(f"unknown materials: {', '.join(unknown)}")
    bad = sorted({p.substance for p in entry.parts.values()} - set(SUBSTANCES))
    if bad:
        reasons.append(f"unknown substances: {', '.join(bad)} (expected one of {', '.join(SUBSTANCES)})")
    return reasons
