"""Run the canonical stages in order, in-process, with one set of parameters per profile.

`run_stage(name, profile)` is what `photoshape run`, `photoshape demo` and the Prefect flows call; it
dispatches to the stage's pipeline function with the profile's parameters. A profile fixes the
sizes that trade quality for time: `tiny` (CI, seconds), `small` (the README demo: the whole
pipeline on 2 CPU cores in minutes), `medium` (accuracy figures mean something), `default` (real
collections on a CPU machine) and `paper` (the paper's settings, for a GPU machine).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import sqlalchemy as sa

from photoshape_flow.config import Settings, get_settings
from photoshape_flow.db import models as m
from photoshape_flow.db.session import session_scope
from photoshape_flow.vocab import STAGES

log = logging.getLogger(__name__)

COLLECTIONS: tuple[str, ...] = ("envmaps", "materials", "shapes", "exemplars")  # ingest order: previews need envmaps


@dataclass(frozen=True)
class Profile:
    """Every knob of a pipeline run that trades quality for time."""

    name: str
    # coarse alignment
    exemplar_topk: int = 8  # shapes kept per exemplar in the reverse index
    shape_topn: int = 12  # exemplars kept per shape (paper: 12)
    # fine alignment
    fine_size: int = 320
    # substances: bootstrap renders + substance network
    bootstrap_count: int = 2000
    substance_size: int = 128
    substance_spp: int = 32
    substance_config: str = "cpu"
    substance_overrides: dict[str, Any] = field(default_factory=dict)
    # training renders + material classifier
    training_count: int = 4000
    training_size: int = 128
    training_spp: int = 32
    classifier_config: str = "cpu"
    classifier_overrides: dict[str, Any] = field(default_factory=dict)
    # inference
    top_k: int = 5
    methods: tuple[str, ...] = ("classifier", "no-classifier", "color-match", "builtin")
    # publish
    publish_max_rank: int = 12  # publish pairs up to this rank per shape
    publish_views: int = 8
    publish_size: int = 256
    publish_spp: int = 64
    publish_formats: tuple[str, ...] = ("glb", "xml", "obj")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


PROFILES: dict[str, Profile] = {
    "tiny": Profile(
        name="tiny", exemplar_topk=2, shape_topn=4, fine_size=96,
        bootstrap_count=24, substance_size=48, substance_spp=4, substance_config="tiny",
        training_count=32, training_size=48, training_spp=4, classifier_config="tiny",
        top_k=3, publish_max_rank=1, publish_views=2, publish_size=48, publish_spp=4,
    ),
    "small": Profile(
        name="small", exemplar_topk=3, shape_topn=6, fine_size=192,
        bootstrap_count=160, substance_size=96, substance_spp=16, substance_config="cpu",
        substance_overrides={"epochs": 20},
        training_count=320, training_size=96, training_spp=16, classifier_config="cpu",
        classifier_overrides={"epochs": 4},
        publish_max_rank=1, publish_views=8, publish_size=160, publish_spp=32,
    ),
    "medium": Profile(
        name="medium", exemplar_topk=4, shape_topn=12, fine_size=256,
        bootstrap_count=1200, substance_size=128, substance_spp=32, substance_config="cpu",
        substance_overrides={"epochs": 60},
        training_count=3000, training_size=128, training_spp=32, classifier_config="cpu",
        classifier_overrides={"epochs": 12, "max_steps_per_epoch": 80, "image_size": 128},
        publish_max_rank=1, publish_views=8, publish_size=256, publish_spp=64,
    ),
    "default": Profile(name="default"),
    "paper": Profile(
        name="paper", exemplar_topk=8, shape_topn=12, fine_size=500,
        bootstrap_count=20000, substance_size=256, substance_spp=128, substance_config="gpu",
        training_count=156000, training_size=384, training_spp=256, classifier_config="paper",
        top_k=10, publish_max_rank=12, publish_size=1280, publish_spp=256,
    ),
}


def get_profile(name: str | Profile, **overrides: Any) -> Profile:
    profile = name if isinstance(name, Profile) else PROFILES.get(name)
    if profile is None:
        raise ValueError(f"unknown profile {name!r}; choose from {', '.join(PROFILES)}")
    return replace(profile, **overrides) if overrides else profile


# --- stages ----------------------------------------------------------------------------------------

def inbox(settings: Settings) -> Path:
    """Where `photoshape run ingest` looks for new files: <data_root>/inbox/{envmaps,materials,shapes,exemplars}."""
    return settings.data_root / "inbox"


def _summary(obj: Any) -> Any:
    """A JSON-friendly summary of whatever a stage function returned."""
    if hasattr(obj, "__dataclass_fields__"):
        return {k: _summary(v) for k, v in asdict(obj).items()}
    if isinstance(obj, dict):
        return {str(k): _summary(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_summary(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def run_ingest(
    settings: Settings,
    roots: dict[str, Sequence[Path]] | None = None,
    source: str | None = None,
    license: str | None = None,
    attribution: str | None = None,
) -> dict[str, Any]:
    """Ingest the four collections (default: the inbox folders), envmaps first so previews can render."""
    from photoshape_flow.pipeline import ingest

    if roots is None:
        base = inbox(settings)
        roots = {name: [base / name] for name in COLLECTIONS if (base / name).is_dir()}
    functions: dict[str, Callable[..., Any]] = {
        "envmaps": ingest.ingest_envmaps, "materials": ingest.ingest_materials,
        "shapes": ingest.ingest_shapes, "exemplars": ingest.ingest_exemplars,
    }
    out: dict[str, Any] = {}
    for name in COLLECTIONS:
        paths = [Path(p) for p in roots.get(name, [])]
        if not paths:
            continue
        kwargs: dict[str, Any] = {"settings": settings}
        if source is not None and name in ("shapes", "exemplars", "materials"):
            kwargs["source"] = source
        if license is not None:
            kwargs["license"] = license
        if attribution is not None:
            kwargs["attribution"] = attribution
        summary = functions[name](paths, **kwargs)
        out[name] = {
            "added": len(summary.added), "present": len(summary.present), "replaced": len(summary.replaced),
            "rejected": [f"{path}: {reason}" for path, reason in summary.rejected],
        }
    return out


def run_coarse(settings: Settings, profile: Profile) -> dict[str, Any]:
    from photoshape_flow.pipeline.coarse_alignment import CoarseConfig, run_coarse_alignment

    config = CoarseConfig(exemplar_topk=profile.exemplar_topk, shape_topn=profile.shape_topn)
    return run_coarse_alignment(settings=settings, config=config)


def run_fine(settings: Settings, profile: Profile, pair_ids: Sequence[int] | None = None) -> dict[str, Any]:
    from photoshape_flow.align.fine import FineParams
    from photoshape_flow.pipeline.fine_alignment import run_fine_alignment

    return run_fine_alignment(pair_ids, settings, params=FineParams(size=profile.fine_size))


def run_substances_stage(settings: Settings, profile: Profile) -> dict[str, Any]:
    from photoshape_flow.pipeline.substances import run_substances

    return run_substances(
        settings, bootstrap_count=profile.bootstrap_count, size=profile.substance_size,
        spp=profile.substance_spp, train_config=profile.substance_config,
        train_overrides=dict(profile.substance_overrides) or None,
    )


def run_training_renders_stage(settings: Settings, profile: Profile) -> dict[str, Any]:
    from photoshape_flow.pipeline.training_renders import run_training_renders

    return run_training_renders("training", profile.training_count, profile.training_size, profile.training_spp,
                                settings)


def run_training_stage(settings: Settings, profile: Profile) -> dict[str, Any]:
    from photoshape_flow.pipeline.training import run_training

    classifier_id = run_training(profile.classifier_config, settings=settings,
                                 overrides=dict(profile.classifier_overrides) or None)
    with session_scope(settings.resolved_database_url) as session:
        clf = session.get(m.Classifier, classifier_id)
        return {"classifier_id": classifier_id, "name": clf.name, "status": clf.status, "metrics": clf.metrics}


def run_inference_stage(settings: Settings, profile: Profile, pair_ids: Sequence[int] | None = None) -> dict[str, Any]:
    from photoshape_flow.pipeline.inference import run_all_methods

    summaries = run_all_methods(profile.methods, settings=settings, top_k=profile.top_k, pair_ids=pair_ids)
    return {s.method_key: _summary(s) for s in summaries}


def publish_pair_ids(settings: Settings, max_rank: int) -> list[int]:
    with session_scope(settings.resolved_database_url) as session:
        return list(session.execute(
            sa.select(m.Pair.id).where(m.Pair.rank <= max_rank, ~m.Pair.exclude).order_by(m.Pair.id)
        ).scalars())


def gallery_dir(settings: Settings) -> Path:
    return settings.data_root / "gallery"


def run_publish_stage(settings: Settings, profile: Profile, pair_ids: Sequence[int] | None = None) -> dict[str, Any]:
    """PhotoShape renders and exports of the best pairs of every shape, then the gallery."""
    from photoshape_flow.pipeline.gallery_site import write_gallery_site
    from photoshape_flow.pipeline.publish import run_publish

    ids = list(pair_ids) if pair_ids is not None else publish_pair_ids(settings, profile.publish_max_rank)
    summary = run_publish(ids, None, settings, views=profile.publish_views, size=profile.publish_size,
                          spp=profile.publish_spp, formats=profile.publish_formats)
    index = write_gallery_site(gallery_dir(settings), None, settings)
    return {"publish": _summary(summary), "gallery": str(index)}


STAGE_FUNCTIONS: dict[str, Callable[..., Any]] = {
    "ingest": lambda settings, profile, **kw: run_ingest(settings, **kw),
    "coarse-alignment": run_coarse,
    "fine-alignment": run_fine,
    "substances": run_substances_stage,
    "training-renders": run_training_renders_stage,
    "training": run_training_stage,
    "inference": run_inference_stage,
    "publish": run_publish_stage,
}
assert tuple(STAGE_FUNCTIONS) == STAGES


@dataclass
class StageResult:
    stage: str
    seconds: float
    summary: Any


def run_stage(stage: str, profile: str | Profile = "default", settings: Settings | None = None,
              **kwargs: Any) -> StageResult:
    """Run one canonical stage with the profile's parameters; returns its summary and wall time."""
    if stage not in STAGE_FUNCTIONS:
        raise ValueError(f"unknown stage {stage!r}; stages: {', '.join(STAGES)}")
    settings = settings or get_settings()
    prof = get_profile(profile)
    start = time.perf_counter()
    log.info("stage %s (profile %s) starting", stage, prof.name)
    summary = STAGE_FUNCTIONS[stage](settings, prof, **kwargs)
    seconds = time.perf_counter() - start
    log.info("stage %s finished in %.1f s", stage, seconds)
    return StageResult(stage, seconds, _summary(summary))


def run_all(profile: str | Profile = "default", settings: Settings | None = None,
            stages: Sequence[str] = STAGES, ingest_roots: dict[str, Sequence[Path]] | None = None,
            ingest_source: str | None = None, ingest_license: str | None = None,
            ingest_attribution: str | None = None,
            on_stage: Callable[[StageResult], None] | None = None) -> list[StageResult]:
    """Every stage in canonical order; each resumes from what earlier runs recorded."""
    results = []
    for stage in STAGES:
        if stage not in stages:
            continue
        kwargs: dict[str, Any] = {}
        if stage == "ingest":
            kwargs = {"roots": ingest_roots, "source": ingest_source, "license": ingest_license,
                      "attribution": ingest_attribution}
        result = run_stage(stage, profile, settings, **kwargs)
        results.append(result)
        if on_stage is not None:
            on_stage(result)
    return results
