"""Typed profiles: every knob of a pipeline run that trades quality for time, one dataclass per stage.

A `Profile` nests one frozen config per stage; the classifier's and the substance network's training
configurations are fields of it (`training`, `substances.network`), built from their presets, so a
profile is the single table a run reads. `tiny` (CI, seconds), `small` (the README demo: the whole
pipeline on 2 CPU cores in minutes), `medium` (accuracy figures mean something), `default` (real
collections on a CPU machine) and `paper` (the paper's settings, for a GPU machine).

Overrides use dotted paths (`training.epochs=3`, `publish.formats=glb,obj`) and are validated
against the field types, so a typo fails before any work starts. `ResolvedProfile` keeps the name
and the overrides next to the resulting profile: that is what a run records in `pipeline_run`.
This module imports no torch, database or Prefect code, so the CLI and flows can load it cheaply.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from photoshape_flow.classify.configs import CONFIGS as CLASSIFIER_PRESETS
from photoshape_flow.classify.configs import ClassifierConfig
from photoshape_flow.classify.substance_configs import PRESETS as SUBSTANCE_PRESETS
from photoshape_flow.classify.substance_configs import SubstanceTrainConfig
from photoshape_flow.export.formats import DEFAULT_FORMATS, EXPORTERS
from photoshape_flow.method_keys import FIT, method_of
from photoshape_flow.vocab import ASSIGNMENT_METHODS


class ProfileError(ValueError):
    """An unknown profile name or an override that does not fit the profile's fields."""


@dataclass(frozen=True)
class IngestConfig:
    """Sizes of what ingest derives from each input."""

    exemplar_size: int = 512  # stored exemplar crop (pixels, square)
    previews: bool = True  # render a preview of every new material
    preview_size: int = 128


@dataclass(frozen=True)
class CoarseAlignmentConfig:
    """Retrieval breadth (section 4.1): the reverse index keeps `exemplar_topk` shapes per exemplar."""

    exemplar_topk: int = 8
    shape_topn: int = 12  # exemplars kept per shape (paper: 12)


@dataclass(frozen=True)
class FineAlignmentConfig:
    """Working resolution of the flow warp and the dense CRF (section 4.2)."""

    size: int = 320


def _check_exposure(section: str, exposure: str) -> None:
    if exposure not in ("as-is", "metered"):
        raise ProfileError(f"{section}.exposure: {exposure!r} is not as-is or metered")


@dataclass(frozen=True)
class SubstancesConfig:
    """Bootstrap renders and the substance network trained on them (section 4.3)."""

    bootstrap_count: int = 2000
    size: int = 128
    spp: int = 32
    network: SubstanceTrainConfig = SUBSTANCE_PRESETS["cpu"]
    exposure: str = "as-is"  # of the bootstrap renders, as `TrainingRendersConfig.exposure`

    def __post_init__(self) -> None:
        _check_exposure("substances", self.exposure)


@dataclass(frozen=True)
class TrainingRendersConfig:
    """Randomized renders conditioned on the part substances (section 5.1)."""

    count: int = 4000
    size: int = 128
    spp: int = 32
    # the envmap's radiance scale per render (U(lo, hi)): the exposures photos are taken at
    env_scale_range: tuple[float, float] = (0.9, 1.2)
    # "as-is": each envmap at its ingested radiance; "metered": scaled to the collection's median mean
    # luminance first (a camera's auto-exposure; real HDRIs differ 5x in mean radiance)
    exposure: str = "as-is"

    def __post_init__(self) -> None:
        low, high = self.env_scale_range
        if not 0 < low <= high:
            raise ProfileError(f"training_renders.env_scale_range: need 0 < low <= high, got {self.env_scale_range}")
        _check_exposure("training_renders", self.exposure)


@dataclass(frozen=True)
class InferenceConfig:
    """How many materials each part keeps, and which methods rank them (ours and the baselines)."""

    top_k: int = 5
    methods: tuple[str, ...] = ASSIGNMENT_METHODS

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in ASSIGNMENT_METHODS]
        if unknown:
            raise ProfileError(f"inference.methods: unknown method {unknown[0]!r}; "
                               f"choose from {', '.join(ASSIGNMENT_METHODS)}")


@dataclass(frozen=True)
class FitConfig:
    """Fit by rendering (`fitting.fit`): candidates per part, render quality, lighting search, cost weights.

    The cost weights and the scores' temperature are fitted per classifier on `calibration_cases`
    validation renders made to look like aligned product photos (`fitting.calibration`,
    docs/decisions.md D34), never on exemplars or evaluation worlds, at `blur` (D64). The five weights
    are the hand-set fallback (D32), used (and reported as "hand-set") when `calibration_cases` is 0 or
    no validation render yields a usable case; they also light and expose the calibration's own cases.
    """

    top_k: int = 5  # candidates from the current ranking, per part
    size: int = 128  # render and comparison resolution (pixels, square exemplar frame)
    spp: int = 16
    rotations: int = 8  # envmap rotations tried per training envmap for the lighting estimate
    lighting_envmaps: int = 4  # more training envmaps than this: screen all at 2 azimuths, search the best 4
    lighting_rounds: int = 1  # 2+: then select, and light the winners again (worse on validation renders: D42)
    erode: int = 1  # pixels shrunk off each part mask before comparing
    blur: float = 1.0  # Gaussian sigma (pixels) applied to the photo and to every render before comparing
    exposure_stops: float = 2.0  # each candidate judged at its best exposure this far either side of the
    #                              lighting's, in quarter stops (no new renders; 0: the lighting's only; D42)
    color_weight: float = 1.0  # CIELAB mean
    contrast_weight: float = 0.5  # CIELAB standard deviation
    gradient_weight: float = 0.5  # L* gradient-magnitude statistics, two scales
    highlight_weight: float = 0.0  # L* 90th/99th percentiles above the median (gloss); the calibration may
    #                                raise it (hand-set 0: fitted to 0 on the small demo's validation renders, D38)
    deep_weight: float = 0.0  # backbone texture moments (`fit.deep_texture`); the calibration may raise it (D54)
    texture_backbone: str = "none"  # the backbone the deep term reads frames with, e.g. "efficientnet-lite0";
    #                                 "none": no term, no read (measured level on both worlds: D54)
    prior_weight: float = 0.3  # times -log(ranking prior)
    prior_floor: float = 0.02  # prior of candidates the ranking did not propose
    # refinement of the winners (`fit.refine`, D35): only for the pairs publish uses; each part's tint solved
    # like for like (D67). Off: validation renders relit worse (D66)
    refine: bool = False
    refine_max_rank: int = 12  # pairs up to this rank per shape (keep equal to publish.max_rank) and each
    #                            exemplar's best pair are refined; the others keep the selection
    refine_iterations: int = 0  # Adam steps on the roughness scale (0: kept; it relit worse, D67)
    refine_uv: bool = False  # search each textured part's UV scale and rotation (relit worse, D67)
    refine_spp: int = 4  # per gradient render (a new seed each step) and per UV-search render
    refine_size: int = 64  # gradient renders' frame (its loss is region statistics: resolution matters little)
    calibration_cases: int = 48  # validation renders the weights are fitted on (0: the hand-set weights)
    calibration_at_exemplar_size: bool = True  # degrade the calibration's photos at the median stored
    #                                           exemplar's side, not the render's (D45)


PUBLISH_METHODS = ("classifier", "fit")  # assignment methods publish can show (`PublishConfig.method`)
DEFAULT_PUBLISH_METHOD = "fit"  # ahead of the classifier's ranking on the second world (D46)


def writing_stage(method: str) -> str:
    """The stage that writes a method's (or method key's) assignments: `fit` its own, inference the others."""
    return "fit" if method_of(method) == FIT else "inference"


@dataclass(frozen=True)
class PublishConfig:
    """Which pairs become PhotoShapes, whose assignments they show, at what quality they are rendered.

    `method` names whose rank-1 assignments publish renders, exports and lists in the gallery: `fit`
    (materials chosen by rendering each pair against its photo), whose rank-1 beats the paper's
    classifier ranking on the second world (docs/decisions.md D46), or `classifier` (each pair's
    newest classifier). The CLI and the flows both read it.
    """

    max_rank: int = 12  # publish pairs up to this rank per shape
    method: str = DEFAULT_PUBLISH_METHOD  # one of PUBLISH_METHODS
    views: int = 8
    size: int = 256
    spp: int = 64
    formats: tuple[str, ...] = DEFAULT_FORMATS

    def __post_init__(self) -> None:
        if self.method not in PUBLISH_METHODS:
            raise ProfileError(f"publish.method: unknown method {self.method!r}; "
                               f"choose from {', '.join(PUBLISH_METHODS)}")
        unknown = [f for f in self.formats if f not in EXPORTERS]
        if unknown:
            raise ProfileError(f"publish.formats: unknown format {unknown[0]!r}; choose from {', '.join(EXPORTERS)}")


@dataclass(frozen=True)
class Profile:
    """One config per stage (attribute = stage name with '_' for '-')."""

    name: str
    ingest: IngestConfig = field(default_factory=IngestConfig)
    coarse_alignment: CoarseAlignmentConfig = field(default_factory=CoarseAlignmentConfig)
    fine_alignment: FineAlignmentConfig = field(default_factory=FineAlignmentConfig)
    substances: SubstancesConfig = field(default_factory=SubstancesConfig)
    training_renders: TrainingRendersConfig = field(default_factory=TrainingRendersConfig)
    training: ClassifierConfig = CLASSIFIER_PRESETS["cpu"]
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    fit: FitConfig = field(default_factory=FitConfig)
    publish: PublishConfig = field(default_factory=PublishConfig)

    def stage_config(self, stage: str) -> Any:
        """The config of `stage` (a canonical stage name such as 'fine-alignment')."""
        return getattr(self, stage.replace("-", "_"))

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON (tuples as lists), the form stored with each run."""
        return json.loads(json.dumps(dataclasses.asdict(self)))


_CPU_CLASSIFIER = CLASSIFIER_PRESETS["cpu"]
_CPU_SUBSTANCES = SUBSTANCE_PRESETS["cpu"]
# bootstrap renders at 256 px, the network trained on 128 px crops at that pitch and reading photos at
# 256: parts at twice the detail for the same cost a step (D72). The crops span the pixels the cpu
# preset's crops of a render at its own size span (area shrinks by the square of the scale), so only
# the pitch changes: (0.55, 1.0) -> (0.1375, 0.25)
FINE_SUBSTANCES_SIZE = 256
_FINE_SUBSTANCES = replace(
    _CPU_SUBSTANCES, read_size=FINE_SUBSTANCES_SIZE,
    crop_scale=tuple(a * (_CPU_SUBSTANCES.size / FINE_SUBSTANCES_SIZE) ** 2 for a in _CPU_SUBSTANCES.crop_scale),
)

PROFILES: dict[str, Profile] = {
    "tiny": Profile(
        name="tiny",
        coarse_alignment=CoarseAlignmentConfig(exemplar_topk=2, shape_topn=4),
        fine_alignment=FineAlignmentConfig(size=96),
        substances=SubstancesConfig(bootstrap_count=24, size=48, spp=4, network=SUBSTANCE_PRESETS["tiny"]),
        training_renders=TrainingRendersConfig(count=32, size=48, spp=4),
        training=CLASSIFIER_PRESETS["tiny"],
        inference=InferenceConfig(top_k=3),
        # a smoke profile: the calibration runs, briefly (with `fit.refine=true` the refinement too)
        fit=FitConfig(top_k=3, size=48, spp=4, rotations=2, refine_max_rank=1, refine_iterations=3,
                      refine_size=32, calibration_cases=3),
        publish=PublishConfig(max_rank=1, views=2, size=48, spp=4),
    ),
    "small": Profile(
        name="small",
        coarse_alignment=CoarseAlignmentConfig(exemplar_topk=3, shape_topn=6),
        fine_alignment=FineAlignmentConfig(size=192),
        substances=SubstancesConfig(bootstrap_count=160, size=96, spp=16, network=replace(_CPU_SUBSTANCES, epochs=20)),
        training_renders=TrainingRendersConfig(count=320, size=96, spp=16),
        training=replace(_CPU_CLASSIFIER, epochs=4),
        fit=FitConfig(size=96, spp=8, rotations=4, refine_max_rank=1),
        publish=PublishConfig(max_rank=1, views=8, size=160, spp=32),
    ),
    "medium": Profile(
        name="medium",
        coarse_alignment=CoarseAlignmentConfig(exemplar_topk=4, shape_topn=12),
        fine_alignment=FineAlignmentConfig(size=256),
        substances=SubstancesConfig(bootstrap_count=1200, size=FINE_SUBSTANCES_SIZE, spp=32,
                                    network=replace(_FINE_SUBSTANCES, epochs=60)),
        training_renders=TrainingRendersConfig(count=3000, size=128, spp=32),
        training=replace(_CPU_CLASSIFIER, epochs=12, max_steps_per_epoch=80, image_size=128),
        fit=FitConfig(size=128, spp=8, rotations=4, refine_max_rank=1),
        publish=PublishConfig(max_rank=1, views=8, size=256, spp=64),
    ),
    "default": Profile(name="default",
                       substances=SubstancesConfig(size=FINE_SUBSTANCES_SIZE, network=_FINE_SUBSTANCES)),
    "paper": Profile(
        name="paper",
        coarse_alignment=CoarseAlignmentConfig(exemplar_topk=8, shape_topn=12),
        fine_alignment=FineAlignmentConfig(size=500),
        substances=SubstancesConfig(bootstrap_count=20000, size=256, spp=128, network=SUBSTANCE_PRESETS["gpu"]),
        training_renders=TrainingRendersConfig(count=156000, size=384, spp=256),
        training=CLASSIFIER_PRESETS["paper"],
        inference=InferenceConfig(top_k=10),
        fit=FitConfig(top_k=10, size=256, spp=32, rotations=12),
        publish=PublishConfig(max_rank=12, size=1280, spp=256),
    ),
}


@dataclass(frozen=True)
class ResolvedProfile:
    """A named profile with validated overrides applied: what a run uses and records."""

    name: str
    overrides: tuple[tuple[str, str], ...]
    profile: Profile

    def record(self) -> dict[str, Any]:
        """The JSON stored with a run: name, overrides as given, every resolved value."""
        return {"name": self.name, "overrides": dict(self.overrides), "profile": self.profile.to_dict()}


def get_profile(name: str | Profile) -> Profile:
    """A profile by name (a Profile passes through)."""
    if isinstance(name, Profile):
        return name
    if name not in PROFILES:
        raise ProfileError(f"unknown profile {name!r}; choose from {', '.join(PROFILES)}")
    return PROFILES[name]


def resolve_profile(name: str | Profile, overrides: Sequence[str] | Mapping[str, Any] = ()) -> ResolvedProfile:
    """`name` with `overrides` ('path=value' strings, or a {path: value} mapping) applied and validated."""
    profile = get_profile(name)
    items = list(overrides.items()) if isinstance(overrides, Mapping) else [_split(text) for text in overrides]
    for path, value in items:
        profile = _set(profile, path.split("."), value, path)
    try:
        profile.training.check()
    except ValueError as exc:
        raise ProfileError(f"training: {exc}") from None
    pairs = tuple((path, value if isinstance(value, str) else json.dumps(value)) for path, value in items)
    return ResolvedProfile(profile.name, pairs, profile)


def _split(text: str) -> tuple[str, str]:
    path, sep, value = text.partition("=")
    if not sep or not path.strip():
        raise ProfileError(f"override {text!r} is not of the form section.field=value")
    return path.strip(), value.strip()


def _set(obj: Any, keys: list[str], value: Any, path: str) -> Any:
    """A copy of dataclass `obj` with the field at `keys` set to `value` (coerced to the field's type)."""
    if not dataclasses.is_dataclass(obj):
        raise ProfileError(f"{path}: {type(obj).__name__} has no fields to set")
    hints = typing.get_type_hints(type(obj))
    names = {f.name for f in dataclasses.fields(obj) if f.init}
    key = keys[0]
    if key not in names or key == "name" and obj.__class__ is Profile:
        choices = ", ".join(sorted(n for n in names if not (n == "name" and obj.__class__ is Profile)))
        raise ProfileError(f"{path}: no field {key!r} (choose from {choices})")
    if len(keys) > 1:
        return replace(obj, **{key: _set(getattr(obj, key), keys[1:], value, path)})
    try:
        return replace(obj, **{key: _coerce(value, hints[key], path)})
    except ProfileError:
        raise
    except ValueError as exc:  # a config's own validation (e.g. an unknown choice)
        raise ProfileError(f"{path}: {exc}") from None


def _coerce(value: Any, hint: Any, path: str) -> Any:
    """`value` (a string from the command line, or JSON-like) as an instance of type `hint`."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            if type(None) in args:
                return None
        errors = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _coerce(value, arg, path)
            except ProfileError as exc:
                errors.append(str(exc))
        raise ProfileError(errors[0] if errors else f"{path}: cannot be None")
    if origin is tuple:
        parts = value if isinstance(value, list | tuple) else [p for p in str(value).split(",") if p.strip()]
        inner = args[0] if args and (len(args) == 2 and args[1] is Ellipsis) else None
        if inner is None and args and len(args) != len(parts):
            raise ProfileError(f"{path}: expected {len(args)} comma-separated values, got {len(parts)}")
        kinds = [inner] * len(parts) if inner is not None else list(args) or [str] * len(parts)
        values = [p.strip() if isinstance(p, str) else p for p in parts]
        return tuple(_coerce(v, k, path) for v, k in zip(values, kinds, strict=True))
    if hint is bool:
        if isinstance(value, bool):
            return value
        text = str(value).lower()
        if text in ("1", "true", "yes", "on"):
            return True
        if text in ("0", "false", "no", "off"):
            return False
        raise ProfileError(f"{path}: {value!r} is not a boolean (true/false)")
    if hint in (int, float, str):
        if hint is int and isinstance(value, float) and not value.is_integer():
            raise ProfileError(f"{path}: {value!r} is not an integer")
        try:
            return hint(value)
        except (TypeError, ValueError):
            raise ProfileError(f"{path}: {value!r} is not a valid {hint.__name__}") from None
    raise ProfileError(f"{path}: fields of type {hint} cannot be set from the command line")
