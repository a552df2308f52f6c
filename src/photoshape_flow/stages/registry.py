"""The stage registry: every pipeline stage declared once (the project's composition root).

`photoshape run`, `photoshape status`, the work claims, the Prefect flows, the deployments and the
checks on `prefect.yaml` all read `REGISTRY`; no other table maps stage names to code. A new stage
is one module with `run(ctx, cfg, work=None) -> StageReport` (plus `plan`/`finish` if it fans out,
and `versions` if an item's inputs can change under the same id), one config dataclass on
`Profile`, and one entry here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.alignment import coarse_alignment_stage as coarse_alignment
from photoshape_flow.alignment import fine_alignment_stage as fine_alignment
from photoshape_flow.fitting import fit_stage as fit
from photoshape_flow.ingest import ingest_stage as ingest
from photoshape_flow.pipeline import progress
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import Profile
from photoshape_flow.publish import publish_stage as publish
from photoshape_flow.recognition import inference_stage as inference
from photoshape_flow.recognition import substances_stage as substances
from photoshape_flow.recognition import training_renders_stage as training_renders
from photoshape_flow.recognition import training_stage as training


@dataclass(frozen=True, repr=False)
class Stage:
    """One pipeline stage: its code, the tables it reads and writes, its counter, how it fans out."""

    name: str
    description: str  # one line: the flow's and the deployment's description
    run: Callable[[StageContext, Any, Any], StageReport]
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    progress: Callable[[Session], progress.StageProgress]
    plan: Callable[[StageContext, Any], list[WorkUnit]] | None = None  # set: the stage fans out
    finish: Callable[[StageContext, Any], StageReport] | None = None  # after every unit of a fan-out
    # a unit's item id -> key of its inputs: a done item whose key changed is claimed again (an id
    # left out is keyed by the config alone); given the unit, not its ids, since parts differ
    versions: Callable[[StageContext, Any, WorkUnit], dict[int, str]] | None = None
    batch_size: int = 32  # items per unit of work in a fan-out
    claims_itself: bool = False  # the pipeline claims its items (finer than a batch)
    exclusive: bool = False  # whole-stage work that must not run twice at once (one flow run at a time)
    # part of retraining: makes a network's training data, trains it, or applies the retrained network
    # (hours at paper scale); a triggered re-run leaves it to the nightly run (`pipeline.new_materials`)
    retraining: bool = False

    @property
    def fans_out(self) -> bool:
        return self.plan is not None

    def __repr__(self) -> str:
        fan = f", fans out in batches of {self.batch_size}" if self.fans_out else ""
        return f"Stage({self.name!r}: reads {', '.join(self.reads) or '-'}; writes {', '.join(self.writes)}{fan})"

    def config(self, profile: Profile) -> Any:
        """This stage's section of a profile."""
        return profile.stage_config(self.name)


REGISTRY: tuple[Stage, ...] = (
    Stage(
        "ingest", "Ingest the four collections (default: everything in <data_root>/inbox).",
        ingest.run, reads=(), writes=("shape", "part", "exemplar", "material", "envmap", "rendering"),
        progress=progress.ingest_progress,
    ),
    Stage(
        "coarse-alignment", "Viewpoint sweeps and HOG descriptors, exact retrieval, shape-exemplar pairs.",
        coarse_alignment.run, reads=("shape", "exemplar"),
        writes=("viewpoint_set", "view_feature", "exemplar_feature", "exemplar_match", "pair"),
        progress=progress.coarse_alignment_progress, plan=coarse_alignment.plan, finish=coarse_alignment.finish,
        batch_size=8, versions=coarse_alignment.versions,
    ),
    Stage(
        "fine-alignment", "Project each pair's parts, flow-warp them onto the exemplar, clean with a dense CRF.",
        fine_alignment.run, reads=("pair", "shape", "exemplar"), writes=("alignment", "rendering"),
        progress=progress.fine_alignment_progress, plan=fine_alignment.plan, versions=fine_alignment.versions,
    ),
    Stage(
        "substances", "Bootstrap renders, the substance network, and a substance per aligned part.",
        substances.run, reads=("alignment", "material", "envmap", "shape"),
        writes=("rendering", "classifier", "part_substance"), progress=progress.substances_progress,
        plan=substances.plan, finish=substances.finish, batch_size=16, versions=substances.versions, exclusive=True,
        retraining=True,
    ),
    Stage(
        "training-renders", "Randomized renders conditioned on part substances (section 5.1), resumable.",
        training_renders.run, reads=("part_substance", "material", "envmap", "shape"), writes=("rendering",),
        progress=progress.training_renders_progress, plan=training_renders.plan, batch_size=16,
        versions=training_renders.versions, retraining=True,
    ),
    Stage(
        "training", "Train (or resume, or fine-tune when materials were added) the material classifier.",
        training.run, reads=("rendering", "material"), writes=("classifier",), progress=progress.training_progress,
        exclusive=True, retraining=True,
    ),
    Stage(
        "inference", "Ranked materials per part for the classifier and the baselines (section 6.1).",
        inference.run, reads=("alignment", "part_substance", "classifier", "material"), writes=("assignment",),
        progress=progress.inference_progress, plan=inference.plan, batch_size=64, claims_itself=True,
        retraining=True,
    ),
    Stage(
        "fit", "Materials chosen by rendering each pair against its photo (lighting, candidates, scores).",
        fit.run, reads=("assignment", "alignment", "exemplar", "material", "envmap", "shape"),
        writes=("assignment", "exemplar"), progress=progress.fit_progress, plan=fit.plan, batch_size=16,
        claims_itself=True,
    ),
    Stage(
        "publish", "PhotoShape renders and exports of the best pairs, then the gallery.",
        publish.run, reads=("assignment", "pair", "shape", "material", "envmap"), writes=("rendering",),
        progress=progress.publish_progress, plan=publish.plan, finish=publish.finish, batch_size=8,
        versions=publish.versions,
    ),
)

STAGES: dict[str, Stage] = {stage.name: stage for stage in REGISTRY}
STAGE_NAMES: tuple[str, ...] = tuple(STAGES)


def get_stage(name: str) -> Stage:
    if name not in STAGES:
        raise ValueError(f"unknown stage {name!r}; stages: {', '.join(STAGE_NAMES)}")
    return STAGES[name]
