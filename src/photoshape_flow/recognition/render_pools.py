"""The pools a training render draws from, and the train/val split (section 5.1).

Splits are by shapes and environment maps, never by images: `load_pools` reads, once per run, the
usable shapes with their parts, the pose prior of the coarse-alignment pairs, the enabled materials by
substance and the envmaps, each assigned to ``train`` or ``val``, and (training round) the part
substances; `split_counts` divides a round's items between the splits. The render loop that samples
from them is `recognition.training_renders`.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import sqlalchemy as sa

from photoshape_flow.db import models as m
from photoshape_flow.hashing import item_seed
from photoshape_flow.synth.priors import observed_prior
from photoshape_flow.synth.spec import PairCandidate, PairPosePrior, PartInfo
from photoshape_flow.vocab import STATUS_OK, SUBSTANCES

Round = Literal["bootstrap", "training"]
ROUNDS: tuple[str, ...] = ("bootstrap", "training")
SPLITS: tuple[str, ...] = ("train", "val")
VAL_FRACTION = 0.1


def normalise_split(split: str | None) -> str:
    return "train" if (split or "train") == "train" else "val"


def _stable_fraction(text: str) -> float:
    return item_seed(text) / 2**64


def derived_val_shapes(keys: Mapping[int, str], fraction: float = VAL_FRACTION) -> set[int]:
    """A deterministic `fraction` of the shapes (at least one when there are two or more) as val."""
    if len(keys) < 2:
        return set()
    n_val = max(1, int(round(fraction * len(keys))))
    ranked = sorted(keys, key=lambda sid: (_stable_fraction(keys[sid]), sid))
    return set(ranked[:n_val])


@dataclass
class RenderPools:
    """Everything the sampler draws from, per split, loaded once per run."""

    priors: dict[str, PairPosePrior]
    envmaps: dict[str, list[int]]
    parts: dict[int, list[PartInfo]]
    materials_by_substance: dict[str, list[int]]
    # pair -> part -> the substance network's probabilities over the part (None: unobserved)
    part_substances: dict[int, dict[int, dict[str, float] | None]] | None
    shape_substances: dict[int, dict[int, list[str]]]
    shape_split: dict[int, str]
    split_source: str
    pose_source: str
    warnings: list[str] = field(default_factory=list)


def load_pools(session: sa.orm.Session, round: Round, val_fraction: float = VAL_FRACTION) -> RenderPools:
    """Read shapes, parts, pairs, materials, envmaps and (training round) part substances."""
    warnings: list[str] = []
    shapes = session.execute(
        sa.select(m.Shape.id, m.Shape.source, m.Shape.source_id, m.Shape.split).where(
            m.Shape.status == STATUS_OK, ~m.Shape.exclude, m.Shape.mesh_blob.is_not(None)
        )
    ).all()
    parts: dict[int, list[PartInfo]] = defaultdict(list)
    for part_id, shape_id, index, name in session.execute(
        sa.select(m.Part.id, m.Part.shape_id, m.Part.index, m.Part.name).order_by(m.Part.shape_id, m.Part.index)
    ):
        parts[shape_id].append(PartInfo(part_id=part_id, index=index, name=name or ""))
    shapes = [s for s in shapes if parts.get(s.id)]
    if not shapes:
        raise ValueError("no usable shape (status ok, not excluded, with a mesh and parts)")

    shape_split = {s.id: normalise_split(s.split) for s in shapes}
    split_source = "shape.split"
    if val_fraction > 0 and "val" not in shape_split.values():
        held_out = derived_val_shapes({s.id: f"{s.source}/{s.source_id}" for s in shapes}, val_fraction)
        shape_split = {sid: ("val" if sid in held_out else "train") for sid in shape_split}
        split_source = "derived" if held_out else "none"
        if held_out:
            warnings.append(f"no val shapes in shape.split: held out {len(held_out)} shape(s) by hash")

    materials: dict[str, list[int]] = {s: [] for s in SUBSTANCES}
    for material_id, substance in session.execute(
        sa.select(m.Material.id, m.Material.substance).where(m.Material.enabled, m.Material.status == STATUS_OK)
    ):
        if substance in materials:
            materials[substance].append(material_id)
    if not any(materials.values()):
        raise ValueError("no enabled material with a known substance")

    envmaps: dict[str, list[int]] = {"train": [], "val": []}
    for envmap_id, split in session.execute(
        sa.select(m.Envmap.id, m.Envmap.split).where(
            m.Envmap.enabled, m.Envmap.status == STATUS_OK, m.Envmap.blob.is_not(None)
        )
    ):
        envmaps[normalise_split(split)].append(envmap_id)
    if not envmaps["train"] and not envmaps["val"]:
        raise ValueError("no enabled environment map")
    for split, other in (("val", "train"), ("train", "val")):
        if not envmaps[split]:
            envmaps[split] = list(envmaps[other])
            warnings.append(f"no {split} envmaps: {split} items use the {other} envmaps")

    pair_rows = session.execute(
        sa.select(m.Pair.id, m.Pair.shape_id, m.Pair.azimuth, m.Pair.elevation)
        .join(m.Exemplar, m.Exemplar.id == m.Pair.exemplar_id)
        .where(~m.Pair.exclude, ~m.Exemplar.exclude, m.Pair.shape_id.in_(list(shape_split)))
        .order_by(m.Pair.id)
    ).all()

    part_substances: dict[int, dict[int, dict[str, float] | None]] | None = None
    shape_substances: dict[int, dict[int, list[str]]] = defaultdict(lambda: defaultdict(list))
    if round == "training":
        part_substances = defaultdict(dict)
        rows = session.execute(
            sa.select(m.PartSubstance.pair_id, m.PartSubstance.part_id, m.PartSubstance.observed,
                      m.PartSubstance.substance, m.PartSubstance.probs, m.Pair.shape_id)
            .join(m.Pair, m.Pair.id == m.PartSubstance.pair_id)
            .order_by(m.PartSubstance.pair_id, m.PartSubstance.part_id)
        ).all()
        for pair_id, part_id, observed, substance, probs, shape_id in rows:
            # the stored probabilities (beside `background` and the map's blob name), else the label alone
            belief = (observed_prior(probs) or observed_prior(substance)) if observed else {}
            part_substances[pair_id][part_id] = belief or None
            if observed and substance:
                shape_substances[shape_id][part_id].append(substance)
        with_substances = [p for p in pair_rows if p.id in part_substances]
        if with_substances:
            candidates_rows = with_substances
        else:
            candidates_rows = pair_rows
            warnings.append("training round without PartSubstance rows: every part uses the prior")
    else:
        candidates_rows = pair_rows

    priors: dict[str, PairPosePrior] = {}
    if pair_rows:
        poses = tuple((float(p.azimuth), float(p.elevation)) for p in pair_rows)
        pose_ids = tuple(int(p.id) for p in pair_rows)
        pose_source = "pairs"
        for split in SPLITS:
            cands = tuple(PairCandidate(p.shape_id, p.id) for p in candidates_rows if shape_split[p.shape_id] == split)
            priors[split] = PairPosePrior(candidates=cands, poses=poses, source=pose_source, pose_ids=pose_ids)
    else:
        pose_source = "default"
        warnings.append("no pairs: sampling shapes with the default front-hemisphere pose prior")
        for split in SPLITS:
            cands = [PairCandidate(sid, None) for sid in sorted(shape_split) if shape_split[sid] == split]
            priors[split] = PairPosePrior.default_poses(cands)
    return RenderPools(
        priors=priors,
        envmaps=envmaps,
        parts=dict(parts),
        materials_by_substance=materials,
        part_substances=None if part_substances is None else {k: dict(v) for k, v in part_substances.items()},
        shape_substances={k: {p: list(v) for p, v in d.items()} for k, d in shape_substances.items()},
        shape_split=shape_split,
        split_source=split_source,
        pose_source=pose_source,
        warnings=warnings,
    )


def split_counts(count: int, pools: RenderPools, val_fraction: float = VAL_FRACTION) -> dict[str, int]:
    """Items per split: `val_fraction` of `count` (rounded, at least 1 when count >= 2) when val exists."""
    has_val = bool(pools.priors.get("val") and pools.priors["val"].candidates)
    has_train = bool(pools.priors.get("train") and pools.priors["train"].candidates)
    n_val = 0
    if has_val and val_fraction > 0:
        n_val = max(1, int(round(val_fraction * count))) if count >= 2 or not has_train else 0
    if not has_train:
        n_val = count
    return {"train": count - n_val, "val": n_val}
