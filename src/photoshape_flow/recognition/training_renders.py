"""Stage: synthetic training renders (section 5.1), in two rounds.

- ``bootstrap``: part substances drawn *without* exemplar evidence (a weak part-name prior mixed with
  uniform, `synth.priors`); these renders train the substance network (`pipeline.substances`).
- ``training``: part substances from the PartSubstance rows of each pair (the paper's substance
  prior); unobserved parts use the substances the same part got in other pairs, else the name prior.
  This round is what the material classifier trains on.

Items are keyed ``<round>/<split>/<index:06d>`` (`synth.spec.item_key`) and every random number of an
item derives from that key and the global seed, so re-running with the same inputs skips finished
items and a larger `count` only adds new ones. An item is skipped when its Rendering row
(kind = round, key) exists with the same `params_hash` (spec, size, spp, mesh, material and envmap
content) and status ok or rejected; failed items are retried. Since the sampler's discrete choices
are rendezvous hashes, adding a material, pair or envmap changes (and re-renders) only the items the
newcomer wins, not the whole set.

Splits are by shapes and environment maps, never by images: a ``train`` item draws its pair from
train shapes and its envmap from train envmaps, a ``val`` item from val ones; `val_fraction` of the
items are val items. `shape.split` / `envmap.split` decide (anything but "train" counts as val). When
no shape is val (tiny collections) a deterministic 10% of the shapes, by a hash of their source id,
is held out instead, and when there are no val envmaps the val items reuse the train envmaps; the
summary says so in `split_source` / `warnings`.

Pose prior: the (azimuth, elevation) of every non-excluded coarse-alignment pair. Without pairs the
candidates are the shapes themselves (pair_id None) with a fixed front-hemisphere prior
(`synth.spec.DEFAULT_POSE_*`): azimuth in [-pi/2, pi/2], elevation in [0, pi/6].

Over-exposed renders (more than 5% of foreground pixels with a channel >= 0.99) are kept as rows with
status ``rejected`` (their images too, for inspection) and are not used for training.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import sqlalchemy as sa

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.hashing import item_seed, stable_hash
from photoshape_flow.pipeline.render_inputs import envmap_spec, material_spec
from photoshape_flow.pipeline.renderings import record_rendering
from photoshape_flow.progress_sink import Progress, no_progress
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.synth.example import SATURATION_THRESHOLD, render_training_example
from photoshape_flow.synth.spec import (
    ENV_SCALE_RANGE,
    SPEC_VERSION,
    PairCandidate,
    PairPosePrior,
    PartInfo,
    RenderSpec,
    item_key,
    metered_gains,
    spec_for_key,
)
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, STATUS_REJECTED, SUBSTANCES

log = logging.getLogger(__name__)

Round = Literal["bootstrap", "training"]
ROUNDS: tuple[str, ...] = ("bootstrap", "training")
SPLITS: tuple[str, ...] = ("train", "val")
# how an envmap lights a training render: as ingested, or metered (`synth.spec.metered_gains`)
EXPOSURES: tuple[str, ...] = ("as-is", "metered")
VAL_FRACTION = 0.1
CODE_VERSION = f"training-renders-v{SPEC_VERSION}"


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
    part_substances: dict[int, dict[int, str | None]] | None
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

    part_substances: dict[int, dict[int, str | None]] | None = None
    shape_substances: dict[int, dict[int, list[str]]] = defaultdict(lambda: defaultdict(list))
    if round == "training":
        part_substances = defaultdict(dict)
        rows = session.execute(
            sa.select(m.PartSubstance.pair_id, m.PartSubstance.part_id, m.PartSubstance.observed,
                      m.PartSubstance.substance, m.Pair.shape_id)
            .join(m.Pair, m.Pair.id == m.PartSubstance.pair_id)
            .order_by(m.PartSubstance.pair_id, m.PartSubstance.part_id)
        ).all()
        for pair_id, part_id, observed, substance, shape_id in rows:
            value = substance if observed else None
            part_substances[pair_id][part_id] = value
            if value:
                shape_substances[shape_id][part_id].append(value)
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


@dataclass
class RenderInputs:
    """Per-run caches of a render spec's rows and derived render inputs (meshes, material and envmap specs)."""

    store: BlobStore
    shapes: dict[int, Any] = field(default_factory=dict)
    meshes: dict[int, Any] = field(default_factory=dict)
    materials: dict[int, Any] = field(default_factory=dict)
    envmaps: dict[int, Any] = field(default_factory=dict)
    # envmap id -> radiance gain (metered exposure); empty: every map as ingested
    gains: dict[int, float] = field(default_factory=dict)

    def load(self, session: sa.orm.Session, spec: RenderSpec) -> None:
        if spec.shape_id not in self.shapes:
            self.shapes[spec.shape_id] = session.get(m.Shape, spec.shape_id)
        missing = [p.material_id for p in spec.parts if p.material_id not in self.materials]
        if missing:
            for row in session.execute(sa.select(m.Material).where(m.Material.id.in_(missing))).scalars():
                self.materials[row.id] = row
        if spec.envmap.envmap_id not in self.envmaps:
            self.envmaps[spec.envmap.envmap_id] = session.get(m.Envmap, spec.envmap.envmap_id)

    def params_hash(self, spec: RenderSpec, size: int, spp: int, threshold: float) -> str:
        shape = self.shapes[spec.shape_id]
        materials = {
            str(p.material_id): [self.materials[p.material_id].params_hash, self.materials[p.material_id].maps,
                                 self.materials[p.material_id].params, self.materials[p.material_id].default_scale]
            for p in spec.parts
        }
        envmap = self.envmaps[spec.envmap.envmap_id]
        params = {
            "code": CODE_VERSION,
            "spec": spec.to_dict(),
            "size": size,
            "spp": spp,
            "saturation_threshold": threshold,
            "mesh": shape.mesh_blob,
            "materials": materials,
            "envmap": envmap.blob,
        }
        if self.gains:  # only when metered, so renders made before metering existed keep their hashes
            params["envmap_gain"] = self.gains.get(spec.envmap.envmap_id, 1.0)
        return stable_hash(params)

    def mesh(self, shape_id: int) -> Any:
        if shape_id not in self.meshes:
            self.meshes[shape_id] = ShapeMesh.from_npz_bytes(self.store.read_bytes(self.shapes[shape_id].mesh_blob))
        return self.meshes[shape_id]

    def material_specs(self, spec: RenderSpec) -> dict[int, Any]:
        return {p.material_id: material_spec(self.materials[p.material_id], self.store) for p in spec.parts}

    def envmap_spec(self, envmap_id: int) -> Any:
        spec = envmap_spec(self.envmaps[envmap_id], self.store)
        return replace(spec, scale=spec.scale * self.gains[envmap_id]) if envmap_id in self.gains else spec


def envmap_mean_luminance(session: sa.orm.Session) -> dict[int, float]:
    """Enabled envmaps' mean luminance as ingest measured it (`meta.stats`; 0 when unknown)."""
    rows = session.execute(sa.select(m.Envmap.id, m.Envmap.meta).where(m.Envmap.enabled.is_(True))).all()
    return {int(i): float(((meta or {}).get("stats") or {}).get("mean_luminance") or 0.0) for i, meta in rows}


def _existing(session: sa.orm.Session, kind: str, keys: Sequence[str]) -> dict[str, tuple[str, str]]:
    rows = session.execute(
        sa.select(m.Rendering.key, m.Rendering.params_hash, m.Rendering.status).where(
            m.Rendering.kind == kind, m.Rendering.key.in_(list(keys))
        )
    ).all()
    return {key: (params_hash, status) for key, params_hash, status in rows}


def run_training_renders(
    round: Round,
    count: int,
    size: int,
    spp: int,
    settings: Settings | None = None,
    batch: int = 16,
    *,
    val_fraction: float = VAL_FRACTION,
    saturation_threshold: float = SATURATION_THRESHOLD,
    renderer: RendererProtocol | None = None,
    env_scale_range: tuple[float, float] = ENV_SCALE_RANGE,
    exposure: str = "as-is",
    indices: Sequence[int] | None = None,
    progress: Progress | None = None,
    store: BlobStore | None = None,
) -> dict[str, Any]:
    """Render `count` items of `round` (resumable, idempotent); returns a summary dict.

    `indices` limits the call to those positions of the round's item list (train items, then
    validation items): a unit of work when the stage fans out over workers. Every item's spec is a
    function of its key and the seed, so any partition renders exactly what one call would.

    Summary: requested/rendered/skipped/rejected/failed counts, items per split, mean render seconds
    per image, pose and split sources, warnings.
    """
    if round not in ROUNDS:
        raise ValueError(f"round must be one of {ROUNDS}, got {round!r}")
    settings = settings or get_settings()
    url = settings.resolved_database_url
    store = store if store is not None else default_store(settings)
    with session_scope(url) as session:
        pools = load_pools(session, round, val_fraction)
    if exposure not in EXPOSURES:
        raise ValueError(f"exposure must be one of {EXPOSURES}, got {exposure!r}")
    per_split = split_counts(count, pools, val_fraction)
    for warning in pools.warnings if indices is None or 0 in indices else ():  # once a round, not per batch
        log.warning("%s round: %s", round, warning)

    keys = [(split, item_key(round, split, i)) for split in SPLITS for i in range(per_split[split])]
    if indices is not None:
        keys = [keys[i] for i in sorted(set(indices)) if 0 <= i < len(keys)]
    inputs = RenderInputs(store=store)
    if exposure == "metered":
        with session_scope(url) as session:
            inputs.gains = metered_gains(envmap_mean_luminance(session))
    summary: dict[str, Any] = {
        "round": round, "requested": count, "splits": per_split, "rendered": 0, "skipped": 0,
        "rejected": 0, "failed": 0, "render_seconds": 0.0, "pose_source": pools.pose_source,
        "split_source": pools.split_source, "warnings": list(pools.warnings), "errors": [],
    }

    def tick() -> None:
        """Items handled so far (rendered, skipped or failed) to the progress sink."""
        handled = summary["rendered"] + summary["skipped"] + summary["failed"]
        (progress or no_progress)(f"{round} renders", handled, len(keys))

    tick()
    for start in range(0, len(keys), max(1, batch)):
        chunk = keys[start : start + max(1, batch)]
        with session_scope(url) as session:
            specs: list[tuple[RenderSpec, str]] = []
            for split, key in chunk:
                spec = spec_for_key(
                    key,
                    settings.seed,
                    pair_pose_prior=pools.priors[split],
                    parts=pools.parts,
                    materials_by_substance=pools.materials_by_substance,
                    envmaps=pools.envmaps[split],
                    part_substances=pools.part_substances,
                    round_=round,
                    split=split,
                    shape_substances=pools.shape_substances,
                    env_scale_range=env_scale_range,
                )
                inputs.load(session, spec)
                specs.append((spec, inputs.params_hash(spec, size, spp, saturation_threshold)))
            existing = _existing(session, round, [s.key for s, _ in specs])
        pending = [
            (spec, h) for spec, h in specs
            if existing.get(spec.key, ("", ""))[0] != h or existing[spec.key][1] not in (STATUS_OK, STATUS_REJECTED)
        ]
        summary["skipped"] += len(specs) - len(pending)
        tick()
        if not pending:
            continue
        if renderer is None:
            renderer = default_renderer(store)
        for spec, params_hash in pending:
            started = time.perf_counter()
            try:
                example = render_training_example(
                    renderer,
                    inputs.mesh(spec.shape_id),
                    spec,
                    inputs.material_specs(spec),
                    inputs.envmap_spec(spec.envmap.envmap_id),
                    size,
                    spp,
                    saturation_threshold=saturation_threshold,
                )
            except Exception as exc:  # one bad item must not stop the batch
                message = f"{spec.key}: {type(exc).__name__}: {exc}"
                log.warning("training render failed: %s", message)
                summary["failed"] += 1
                summary["errors"].append(message)
                with session_scope(url) as session:
                    record_rendering(
                        session, store, kind=round, key=spec.key, images={},
                        params={**spec.to_dict(), "size": size, "spp": spp}, shape_id=spec.shape_id,
                        pair_id=spec.pair_id, envmap_id=spec.envmap.envmap_id, split=spec.split,
                        params_hash=params_hash, status=STATUS_FAILED, error=message[:2000],
                    )
                tick()
                continue
            seconds = time.perf_counter() - started
            summary["render_seconds"] += seconds
            rejected_reason = (
                f"saturated fraction {example.saturated_fraction:.3f} > {saturation_threshold}"
                if example.rejected else None
            )
            with session_scope(url) as session:
                record_rendering(
                    session,
                    store,
                    kind=round,
                    key=spec.key,
                    images={
                        "beauty": example.srgb,
                        "hdr": example.hdr,
                        "part_ids": example.part_ids,
                        "material_ids": example.material_ids,
                        "substance_ids": example.substance_ids,
                    },
                    params={**spec.to_dict(), "size": size, "spp": spp},
                    shape_id=spec.shape_id,
                    pair_id=spec.pair_id,
                    envmap_id=spec.envmap.envmap_id,
                    split=spec.split,
                    seconds=seconds,
                    saturated_fraction=example.saturated_fraction,
                    params_hash=params_hash,
                    status=STATUS_REJECTED if example.rejected else STATUS_OK,
                    error=rejected_reason,
                )
            summary["rendered"] += 1
            summary["rejected"] += int(example.rejected)
            tick()
    done = summary["rendered"]
    summary["seconds_per_image"] = summary["render_seconds"] / done if done else None
    summary["errors"] = summary["errors"][:20]
    log.info(
        "%s renders: %d rendered (%d rejected), %d skipped, %d failed, %s s/image",
        round, done, summary["rejected"], summary["skipped"], summary["failed"],
        "n/a" if not done else f"{summary['seconds_per_image']:.3f}",
    )
    return summary

