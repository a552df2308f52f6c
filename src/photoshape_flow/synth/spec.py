"""Randomised training-render specifications (section 5.1, "Randomized Rendering").

A `RenderSpec` holds every random number behind one synthetic training image: the pair (shape), the
jittered camera, one material and UV transform per part, the environment map with its radiance
scale and rotation. It is plain JSON (`to_dict` / `from_dict`), so the `rendering.params` of a row
reproduce the image exactly, and it is drawn from a generator seeded by the item's natural key
(`hashing.item_seed` of the global seed and the key), so a resumed or repeated run draws the same
numbers for the same key.

Sampling follows the paper, with the original code's bug fixed (its jitter was `uniform(-x, -x)`,
a constant):

1. a pair uniformly from the candidates of the item's split (shapes and envmaps are split, never
   images);
2. a camera pose uniformly from the pose prior (the azimuth/elevation of every coarse-alignment pair),
   jittered by U(-pi/12, pi/12) in azimuth and U(-pi/24, pi/24) in elevation, fov ~ U(50, 60) degrees,
   distance ~ U(1.3, 1.75);
3. per part a substance, drawn from the pair's PartSubstance probabilities when observed (not their
   most likely label: `priors.observed_prior`), else from a prior (see `priors`), then a material
   uniformly among the enabled materials of that substance;
4. an envmap uniformly among the split's envmaps, radiance scale ~ U(0.9, 1.2), rotation ~ U(0, 2 pi);
5. per part a UV transform: scale 2^U(-1, 0.5), rotation U(0, 2 pi), offset U(0, 1)^2, applied on top
   of the renderer's texture-scale formula (UVs / sqrt(D_i) / material scale).

Stable choices: every discrete choice (pair, pose, envmap, material) is a *rendezvous hash* — the
candidate with the highest hash of (item seed, decision, candidate id) — which is uniform over the
candidates like a plain draw, but when the collection grows only the items the newcomer wins change
(about 1/(n+1) of them) instead of every item. Continuous numbers come from the item's generator in
a fixed order, per-part numbers from a generator seeded by (item, part id). So adding a material, a
pair or an envmap re-renders a small share of the items, not the whole training set.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from photoshape_flow.hashing import item_seed
from photoshape_flow.synth import priors

AZIMUTH_JITTER = math.pi / 12
ELEVATION_JITTER = math.pi / 24
FOV_RANGE = (50.0, 60.0)
DISTANCE_RANGE = (1.3, 1.75)
ENV_SCALE_RANGE = (0.9, 1.2)
UV_LOG2_SCALE_RANGE = (-1.0, 0.5)

# Fallback pose prior when there are no pairs yet: product photos look at the front half of a chair
# (+z is the front) from slightly above, so azimuth U(-pi/2, pi/2) and elevation U(0, pi/6).
DEFAULT_POSE_AZIMUTH = (-math.pi / 2, math.pi / 2)
DEFAULT_POSE_ELEVATION = (0.0, math.pi / 6)

SPEC_VERSION = 1


def metered_gains(mean_luminance: Mapping[int, float]) -> dict[int, float]:
    """Each envmap's radiance gain under a camera's auto-exposure: the median of the maps' mean
    luminances over its own, so a dim night map and a bright courtyard light a product alike.

    Photos are exposed for the product, whatever the light; real HDRIs differ in mean radiance by
    5x and more, and without metering their renders come out black or clipped. Maps with no
    positive mean keep gain 1.
    """
    positive = {k: float(v) for k, v in mean_luminance.items() if v and float(v) > 0}
    if not positive:
        return dict.fromkeys(mean_luminance, 1.0)
    reference = float(np.median(list(positive.values())))
    return {k: reference / positive[k] if k in positive else 1.0 for k in mean_luminance}


def item_key(round_: str, split: str, index: int) -> str:
    """The natural key of one training render: ``<round>/<split>/<index:06d>``."""
    return f"{round_}/{split}/{index:06d}"


@dataclass(frozen=True)
class PairCandidate:
    """A shape-exemplar pair the sampler may draw (pair_id None: shape without pairs, fallback)."""

    shape_id: int
    pair_id: int | None = None


@dataclass(frozen=True)
class PartInfo:
    """The parts of a shape as the sampler needs them."""

    part_id: int
    index: int
    name: str = ""


@dataclass(frozen=True)
class PairPosePrior:
    """Candidate pairs of one split plus the empirical camera-pose distribution.

    `poses` holds (azimuth, elevation) in radians, one per coarse-alignment pair (all splits: the
    pose distribution is a property of photos, not of shapes); `source` says where it came from.
    """

    candidates: tuple[PairCandidate, ...]
    poses: tuple[tuple[float, float], ...]
    source: str = "pairs"
    pose_ids: tuple[int, ...] | None = None  # stable id per pose (the pair id); default: position

    def __post_init__(self) -> None:
        if self.pose_ids is not None and len(self.pose_ids) != len(self.poses):
            raise ValueError("pose_ids and poses differ in length")

    @classmethod
    def default_poses(cls, candidates: Sequence[PairCandidate], count: int = 64) -> PairPosePrior:
        """Fallback without pairs: a fixed grid over the front hemisphere (see module constants)."""
        az = np.linspace(*DEFAULT_POSE_AZIMUTH, num=max(2, int(round(math.sqrt(count) * 2))))
        el = np.linspace(*DEFAULT_POSE_ELEVATION, num=max(2, int(round(math.sqrt(count) / 2))))
        poses = tuple((float(a), float(e)) for a in az for e in el)
        return cls(candidates=tuple(candidates), poses=poses, source="default")


@dataclass
class CameraParams:
    azimuth: float
    elevation: float
    distance: float
    fov: float


@dataclass
class EnvmapParams:
    envmap_id: int
    scale: float
    rotation: float


@dataclass
class UVParams:
    scale: float
    rotation: float
    offset: tuple[float, float]


@dataclass
class PartAssignment:
    """The material given to one part and why (substance_source: observed | prior | bootstrap)."""

    part_id: int
    index: int
    name: str
    substance: str
    substance_source: str
    material_id: int
    uv: UVParams


@dataclass
class RenderSpec:
    """Everything random about one training render; JSON round-trips exactly."""

    key: str
    seed: int
    round: str
    split: str
    shape_id: int
    pair_id: int | None
    camera: CameraParams
    pose: tuple[float, float]
    pose_source: str
    envmap: EnvmapParams
    parts: list[PartAssignment] = field(default_factory=list)
    version: int = SPEC_VERSION

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["pose"] = list(self.pose)
        for part in data["parts"]:
            part["uv"]["offset"] = list(part["uv"]["offset"])
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RenderSpec:
        parts = [
            PartAssignment(
                part_id=int(p["part_id"]),
                index=int(p["index"]),
                name=str(p["name"]),
                substance=str(p["substance"]),
                substance_source=str(p["substance_source"]),
                material_id=int(p["material_id"]),
                uv=UVParams(
                    scale=float(p["uv"]["scale"]),
                    rotation=float(p["uv"]["rotation"]),
                    offset=(float(p["uv"]["offset"][0]), float(p["uv"]["offset"][1])),
                ),
            )
            for p in data["parts"]
        ]
        return cls(
            key=str(data["key"]),
            seed=int(data["seed"]),
            round=str(data["round"]),
            split=str(data["split"]),
            shape_id=int(data["shape_id"]),
            pair_id=None if data["pair_id"] is None else int(data["pair_id"]),
            camera=CameraParams(**{k: float(v) for k, v in data["camera"].items()}),
            pose=(float(data["pose"][0]), float(data["pose"][1])),
            pose_source=str(data["pose_source"]),
            envmap=EnvmapParams(
                envmap_id=int(data["envmap"]["envmap_id"]),
                scale=float(data["envmap"]["scale"]),
                rotation=float(data["envmap"]["rotation"]),
            ),
            parts=parts,
            version=int(data.get("version", SPEC_VERSION)),
        )

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def material_by_index(self) -> dict[int, int]:
        """part index (value in part-ID maps) -> material id."""
        return {p.index: p.material_id for p in self.parts}


_MASK64 = np.uint64(0xFFFFFFFFFFFFFFFF)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """The splitmix64 finaliser, vectorised (uint64 arithmetic wraps modulo 2^64)."""
    x = (x + np.uint64(0x9E3779B97F4A7C15)) & _MASK64
    x = ((x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & _MASK64
    x = ((x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & _MASK64
    return x ^ (x >> np.uint64(31))


def _salt(base: int, decision: str) -> np.uint64:
    return np.uint64(item_seed(base, decision, sep=":"))


def rendezvous_index(base: int, decision: str, ids: Sequence[int]) -> int:
    """Index of the id with the highest hash of (base, decision, id): a uniform, collection-stable choice."""
    if len(ids) == 0:
        raise ValueError(f"nothing to choose from for {decision}")
    keys = np.asarray(ids, dtype=np.int64).astype(np.uint64)
    with np.errstate(over="ignore"):
        scores = _splitmix64(keys ^ _splitmix64(np.array([_salt(base, decision)], np.uint64)))
    return int(np.argmax(scores))


def _draw_substance(u: float, prior: Mapping[str, float]) -> str:
    """Inverse-CDF draw over the prior in SUBSTANCES order, from one uniform number."""
    names = list(prior)
    probs = np.array([prior[s] for s in names], np.float64)
    cdf = np.cumsum(probs / probs.sum())
    return names[min(int(np.searchsorted(cdf, u, side="right")), len(names) - 1)]


def sample_render_spec(
    rng: np.random.Generator,
    pair_pose_prior: PairPosePrior,
    parts: Mapping[int, Sequence[PartInfo]],
    materials_by_substance: Mapping[str, Sequence[int]],
    envmaps: Sequence[int],
    part_substances: Mapping[int, Mapping[int, str | Mapping[str, float] | None]] | None = None,
    *,
    key: str = "",
    seed: int = 0,
    round_: str = "training",
    split: str = "train",
    shape_substances: Mapping[int, Mapping[int, Sequence[str]]] | None = None,
    name_prior: bool = True,
    env_scale_range: tuple[float, float] = ENV_SCALE_RANGE,
) -> RenderSpec:
    """Draw one training-render spec (see the module docstring for the distributions).

    - `parts`: shape_id -> its parts; `materials_by_substance`: substance -> enabled material ids;
      `envmaps`: envmap ids of the item's split.
    - `part_substances`: pair_id -> {part_id: the substance network's probabilities over the part (or
      a substance, taken as certain), None when unobserved}; None means the bootstrap round (no
      observations: name prior, or uniform with `name_prior=False`).
    - `shape_substances`: shape_id -> {part_id: substances observed in any pair}, the prior for parts
      the drawn pair does not observe (falls back to the name prior).
    - `env_scale_range`: the envmap's radiance scale is drawn uniformly from it (the exposure a photo
      was taken at); one draw whatever the range, so widening it changes no other choice.

    The draw order is fixed, so the same `rng` state gives the same spec; discrete choices are
    rendezvous hashes (see the module docstring), stable when the collection grows.
    """
    if not pair_pose_prior.candidates:
        raise ValueError("no pair candidates to sample from")
    if not pair_pose_prior.poses:
        raise ValueError("the pose prior is empty")
    if not envmaps:
        raise ValueError("no envmap in this split")
    available = [s for s, ids in materials_by_substance.items() if ids]
    if not available:
        raise ValueError("no enabled material")

    # fixed draw order from the item's generator: one base for the stable choices, then the jitter
    base = int(rng.integers(0, 2**62))
    camera_jitter = (
        float(rng.uniform(-AZIMUTH_JITTER, AZIMUTH_JITTER)),
        float(rng.uniform(-ELEVATION_JITTER, ELEVATION_JITTER)),
        float(rng.uniform(*DISTANCE_RANGE)),
        float(rng.uniform(*FOV_RANGE)),
    )
    env_scale = float(rng.uniform(*env_scale_range))
    env_rotation = float(rng.uniform(0.0, 2 * math.pi))

    candidates = pair_pose_prior.candidates
    candidate = candidates[
        rendezvous_index(
            base, "pair", [c.pair_id if c.pair_id is not None else -1 - c.shape_id for c in candidates]
        )
    ]
    pose_ids = pair_pose_prior.pose_ids or tuple(range(len(pair_pose_prior.poses)))
    pose = pair_pose_prior.poses[rendezvous_index(base, "pose", pose_ids)]
    camera = CameraParams(
        azimuth=float(pose[0] + camera_jitter[0]),
        elevation=float(pose[1] + camera_jitter[1]),
        distance=camera_jitter[2],
        fov=camera_jitter[3],
    )
    envmap_ids = [int(e) for e in envmaps]
    envmap = EnvmapParams(
        envmap_id=envmap_ids[rendezvous_index(base, "envmap", envmap_ids)], scale=env_scale, rotation=env_rotation
    )

    shape_parts = sorted(parts.get(candidate.shape_id, ()), key=lambda p: p.index)
    if not shape_parts:
        raise ValueError(f"shape {candidate.shape_id} has no parts")
    observed = {} if part_substances is None else dict(part_substances.get(candidate.pair_id, {}) or {})
    across = (shape_substances or {}).get(candidate.shape_id, {})
    assignments: list[PartAssignment] = []
    for part in shape_parts:
        part_rng = np.random.default_rng([base, int(part.part_id) & 0x7FFFFFFF])
        u_substance = float(part_rng.uniform())
        uv = UVParams(
            scale=float(2.0 ** part_rng.uniform(*UV_LOG2_SCALE_RANGE)),
            rotation=float(part_rng.uniform(0.0, 2 * math.pi)),
            offset=(float(part_rng.uniform(0.0, 1.0)), float(part_rng.uniform(0.0, 1.0))),
        )
        belief = priors.observed_prior(observed.get(part.part_id))
        if part_substances is not None and any(belief.get(s, 0.0) > 0.0 for s in available):
            substance = _draw_substance(u_substance, priors.restrict(belief, available))
            source = "observed"
        else:
            if part_substances is None:
                prior = priors.name_prior(part.name) if name_prior else priors.uniform_prior()
                source = "bootstrap"
            else:
                prior = priors.empirical_prior(list(across.get(part.part_id, ()))) or priors.name_prior(part.name)
                source = "prior"
            substance = _draw_substance(u_substance, priors.restrict(prior, available))
        material_ids = sorted(int(i) for i in materials_by_substance[substance])
        material_id = material_ids[rendezvous_index(base, f"material:{part.part_id}", material_ids)]
        assignments.append(
            PartAssignment(
                part_id=part.part_id,
                index=part.index,
                name=part.name,
                substance=str(substance),
                substance_source=source,
                material_id=material_id,
                uv=uv,
            )
        )
    return RenderSpec(
        key=key,
        seed=int(seed),
        round=round_,
        split=split,
        shape_id=int(candidate.shape_id),
        pair_id=candidate.pair_id,
        camera=camera,
        pose=(float(pose[0]), float(pose[1])),
        pose_source=pair_pose_prior.source,
        envmap=envmap,
        parts=assignments,
    )


def spec_for_key(key: str, global_seed: int, **kwargs: Any) -> RenderSpec:
    """`sample_render_spec` with the generator seeded from the item's natural key."""
    seed = item_seed(int(global_seed), key, sep=":", bits=63)  # 63 bits: the seed is stored in JSON specs
    return sample_render_spec(np.random.default_rng(seed), key=key, seed=seed, **kwargs)
