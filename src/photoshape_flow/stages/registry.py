"""The stage registry: every pipeline stage declared once (the project's composition root).

`photoshape run`, `photoshape status`, the work claims, the Prefect flows, the deployments and the
checks on `prefect.yaml` all read `REGISTRY`; no other table maps stage names to code. A new stage
is one module in its domain package with `run(ctx, cfg, work=None) -> StageReport` (plus
`plan`/`finish` if it fans out, and `versions` if an item's inputs can change under the same id),
one config dataclass on `Profile`, and one entry here naming that module by its dotted path.

The registry imports no stage module: a stage's module (and the torch, Mitsuba or numpy behind it)
is imported the first time its code is asked for (`Stage.entry`), so flows, `photoshape status`
and `photoshape claims` load the registry in milliseconds and without torch.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from sqlalchemy.orm import Session

from photoshape_flow.pipeline import progress
from photoshape_flow.pipeline.context import StageContext
from photoshape_flow.pipeline.report import StageReport
from photoshape_flow.pipeline.work import WorkUnit
from photoshape_flow.profiles import Profile

PACKAGE = "photoshape_flow"


@dataclass(frozen=True, repr=False)
class Stage:
    """One pipeline stage: its module, the tables it reads and writes, its counter, how it fans out."""

    name: str
    description: str  # one line: the flow's and the deployment's description
    module: str  # dotted path, below the package, of the module with run/plan/finish/versions
    reads: tuple[str, ...]
    writes: tuple[str, ...]
    progress: Callable[[Session], progress.StageProgress]
    fans_out: bool = False  # the module has `plan` (and may have `finish` after every unit, `versions`)
    batch_size: int = 32  # items per unit of work in a fan-out
    claims_itself: bool = False  # the pipeline claims its items (finer than a batch)
    exclusive: bool = False  # whole-stage work that must not run twice at once (one flow run at a time)
    # part of retraining: makes a network's training data, trains it, or applies the retrained network
    # (hours at paper scale); a triggered re-run leaves it to the nightly run (`stages.new_materials`)
    retraining: bool = False

    @property
    def entry(self) -> ModuleType:
        """The stage's module, imported on first use (cached in `sys.modules` thereafter)."""
        return importlib.import_module(f"{PACKAGE}.{self.module}")

    @property
    def run(self) -> Callable[[StageContext, Any, Any], StageReport]:
        return self.entry.run

    @property
    def plan(self) -> Callable[[StageContext, Any], list[WorkUnit]] | None:
        return self.entry.plan if self.fans_out else None

    @property
    def finish(self) -> Callable[[StageContext, Any], StageReport] | None:
        """After every unit of a fan-out (None: the stage has no finishing step)."""
        return getattr(self.entry, "finish", None) if self.fans_out else None

    @property
    def versions(self) -> Callable[[StageContext, Any, WorkUnit], dict[int, str]] | None:
        """A unit's item id -> key of its inputs: a done item whose key changed is claimed again (an id
        left out is keyed by the config alone); given the unit, not its ids, since parts differ."""
        return getattr(self.entry, "versions", None) if self.fans_out else None

    def __repr__(self) -> str:
        fan = f", fans out in batches of {self.batch_size}" if self.fans_out else ""
        return f"Stage({self.name!r}: reads {', '.join(self.reads) or '-'}; writes {', '.join(self.writes)}{fan})"

    def config(self, profile: Profile) -> Any:
        """This stage's section of a profile."""
        return profile.stage_config(self.name)


REGISTRY: tuple[Stage, ...] = (
    Stage(
        "ingest", "Ingest the four collections (default: everything in <data_root>/inbox).",
        "ingest.ingest_stage", reads=(), writes=("shape", "part", "exemplar", "material", "envmap", "rendering"),
        progress=progress.ingest_progress,
    ),
    Stage(
        "coarse-alignment", "Viewpoint sweeps and HOG descriptors, exact retrieval, shape-exemplar pairs.",
        "alignment.coarse_alignment_stage", reads=("shape", "exemplar"),
        writes=("viewpoint_set", "view_feature", "exemplar_feature", "exemplar_match", "pair"),
        progress=progress.coarse_alignment_progress, fans_out=True, batch_size=8,
    ),
    Stage(
        "fine-alignment", "Project each pair's parts, flow-warp them onto the exemplar, clean with a dense CRF.",
        "alignment.fine_alignment_stage", reads=("pair", "shape", "exemplar"), writes=("alignment", "rendering"),
        progress=progress.fine_alignment_progress, fans_out=True,
    ),
    Stage(
        "substances", "Bootstrap renders, the substance network, and a substance per aligned part.",
        "recognition.substances_stage", reads=("alignment", "material", "envmap", "shape"),
        writes=("rendering", "classifier", "part_substance"), progress=progress.substances_progress,
        fans_out=True, batch_size=16, exclusive=True, retraining=True,
    ),
    Stage(
        "training-renders", "Randomized renders conditioned on part substances (section 5.1), resumable.",
        "recognition.training_renders_stage", reads=("part_substance", "material", "envmap", "shape"),
        writes=("rendering",), progress=progress.training_renders_progress, fans_out=True, batch_size=16,
        retraining=True,
    ),
    Stage(
        "training", "Train (or resume, or fine-tune when materials were added) the material classifier.",
        "recognition.training_stage", reads=("rendering", "material"), writes=("classifier",),
        progress=progress.training_progress, exclusive=True, retraining=True,
    ),
    Stage(
        "inference", "Ranked materials per part for the classifier and the baselines (section 6.1).",
        "recognition.inference_stage", reads=("alignment", "part_substance", "classifier", "material"),
        writes=("assignment",), progress=progress.inference_progress, fans_out=True, batch_size=64,
        claims_itself=True, retraining=True,
    ),
    Stage(
        "fit", "Materials chosen by rendering each pair against its photo (lighting, candidates, scores).",
        "fitting.fit_stage", reads=("assignment", "alignment", "exemplar", "material", "envmap", "shape"),
        writes=("assignment", "exemplar"), progress=progress.fit_progress, fans_out=True, batch_size=16,
        claims_itself=True,
    ),
    Stage(
        "publish", "PhotoShape renders and exports of the best pairs, then the gallery.",
        "publish.publish_stage", reads=("assignment", "pair", "shape", "material", "envmap"),
        writes=("rendering",), progress=progress.publish_progress, fans_out=True, batch_size=8,
    ),
)

STAGES: dict[str, Stage] = {stage.name: stage for stage in REGISTRY}
STAGE_NAMES: tuple[str, ...] = tuple(STAGES)


def get_stage(name: str) -> Stage:
    if name not in STAGES:
        raise ValueError(f"unknown stage {name!r}; stages: {', '.join(STAGE_NAMES)}")
    return STAGES[name]
