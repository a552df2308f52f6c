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

Splits are by shapes and environment maps, never by images (`recognition.render_pools`): a ``train``
item draws its pair from train shapes and its envmap from train envmaps, a ``val`` item from val
ones; `val_fraction` of the items are val items. `shape.split` / `envmap.split` decide (anything but
"train" counts as val). When no shape is val (tiny collections) a deterministic 10% of the shapes,
by a hash of their source id, is held out instead, and when there are no val envmaps the val items
reuse the train envmaps; the summary says so in `split_source` / `warnings`.

Pose prior: the (azimuth, elevation) of every non-excluded coarse-alignment pair. Without pairs the
candidates are the shapes themselves (pair_id None) with a fixed front-hemisphere prior
(`synth.spec.DEFAULT_POSE_*`): azimuth in [-pi/2, pi/2], elevation in [0, pi/6].

Over-exposed renders (more than 5% of foreground pixels with a channel >= 0.99) are kept as rows with
status ``rejected`` (their images too, for inspection) and are not used for training.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import sqlalchemy as sa

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.geometry.mesh import ShapeMesh
from photoshape_flow.hashing import stable_hash
from photoshape_flow.pipeline.render_inputs import envmap_spec, material_spec
from photoshape_flow.pipeline.renderings import record_rendering
from photoshape_flow.progress_sink import Progress, no_progress
from photoshape_flow.recognition.render_pools import ROUNDS, SPLITS, VAL_FRACTION, Round, load_pools, split_counts
from photoshape_flow.render.factory import default_renderer
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.store import BlobStore, default_store
from photoshape_flow.synth.example import SATURATION_THRESHOLD, render_training_example
from photoshape_flow.synth.spec import (
    ENV_SCALE_RANGE,
    SPEC_VERSION,
    RenderSpec,
    item_key,
    metered_gains,
    spec_for_key,
)
from photoshape_flow.vocab import STATUS_FAILED, STATUS_OK, STATUS_REJECTED

log = logging.getLogger(__name__)

# how an envmap lights a training render: as ingested, or metered (`synth.spec.metered_gains`)
EXPOSURES: tuple[str, ...] = ("as-is", "metered")
CODE_VERSION = f"training-renders-v{SPEC_VERSION}"


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

