"""What every exemplar of the second world shows, decided from the seed alone (pure: no files, no Blender).

The plan fixes, per exemplar: the catalogue shape (ingested or held out of the collection), one
material per part (a library material, or for the open-library share a hue/roughness/scale variant
of one that is never ingested), the camera, the real HDRI with its rotation and strength, the JPEG
quality and the render seed. Every choice comes from `child_rng(seed, ...)` streams keyed by the
exemplar's index, so adding exemplars never changes the earlier ones, and nothing here looks at a
pipeline output: the world is validation only.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from photoshape_flow.demo.exemplars import sample_camera
from photoshape_flow.demo.seeding import child_rng
from photoshape_flow.vocab import SUBSTANCES

HELDOUT_SHAPE_SLOTS = (0, 3, 5)  # exemplar k shows a non-ingested shape when k % 8 is one of these (3/8)
OPEN_LIBRARY_SLOTS = (1, 4)  # exemplar k uses only non-ingested material variants when k % 7 is one of these (2/7)
MIN_HELDOUT_SHARE = 1 / 3
MIN_OPEN_LIBRARY_SHARE = 1 / 4

# A part's name often says what it is made of (catalogue material groups: "leather", "RED_OAK", "chrome").
SUBSTANCE_KEYWORDS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("leather", ("leather", "cuir", "skin")),
    ("fabric", ("fabric", "cloth", "cushion", "pillow", "textile", "velvet", "linen", "burlap", "plaid")),
    ("wood", ("wood", "oak", "walnut", "pine", "teak", "teca", "beech", "maple", "bamboo", "rattan", "plywood")),
    ("metal", ("metal", "chrome", "steel", "iron", "alu", "brass", "gold", "tube", "leg", "feet", "foot")),
    ("plastic", ("plastic", "rubber", "pvc", "abs", "nylon")),
)
# When the name says nothing: a seating mix (soft parts are the most common material of seating).
FALLBACK_WEIGHTS: dict[str, float] = {"leather": 0.18, "fabric": 0.3, "wood": 0.24, "metal": 0.14, "plastic": 0.14}


@dataclass(frozen=True)
class ShapeInfo:
    """A prepared catalogue shape: its natural key, its parts (name, area) and points for framing."""

    source: str
    source_id: str
    key: str  # file-system-safe name of its exported mesh
    parts: tuple[str, ...]
    category: str
    points: np.ndarray = field(repr=False, compare=False)  # (n, 3) unit-cube vertices (a subsample)
    from_catalog: bool = True  # Debian .sh3f catalogs (may be held out); shared models are always ingested


@dataclass(frozen=True)
class LibraryMaterial:
    name: str
    substance: str
    scale: float  # world size of one tile (unit-cube units)


@dataclass(frozen=True)
class Variant:
    """A non-ingested material: a library material with its hue rotated, roughness and tile size scaled."""

    of: str
    hue_shift_deg: float
    roughness_scale: float
    uv_scale: float

    @property
    def name(self) -> str:
        return (f"{self.of}__h{round(self.hue_shift_deg):+d}_r{round(self.roughness_scale * 100)}"
                f"_s{round(self.uv_scale * 100)}")


@dataclass(frozen=True)
class PartPlan:
    material: str  # the library material (ingested); the variant's parent on the open-library share
    substance: str
    variant: Variant | None = None

    @property
    def shown(self) -> str:
        """The material the photo really shows (a variant's own name)."""
        return self.variant.name if self.variant is not None else self.material


@dataclass(frozen=True)
class ExemplarPlan:
    stem: str
    shape: ShapeInfo
    in_collection: bool
    parts: dict[str, PartPlan]
    camera: dict[str, float]
    envmap: dict[str, Any]  # name, rotation (radians about the vertical), strength (relative)
    jpeg_quality: int
    render_seed: int

    @property
    def open_library(self) -> bool:
        return any(p.variant is not None for p in self.parts.values())

    def to_json(self) -> dict[str, Any]:
        return {
            "stem": self.stem, "shape": {"source": self.shape.source, "source_id": self.shape.source_id},
            "in_collection": self.in_collection, "camera": self.camera, "envmap": self.envmap,
            "jpeg_quality": self.jpeg_quality, "render_seed": self.render_seed,
            "parts": {n: {"material": p.material, "substance": p.substance,
                          "variant": asdict(p.variant) if p.variant else None} for n, p in self.parts.items()},
        }


@dataclass(frozen=True)
class Split:
    collection: tuple[ShapeInfo, ...]  # ingested
    heldout: tuple[ShapeInfo, ...]  # shown in exemplars only


def split_shapes(seed: int, shapes: list[ShapeInfo], heldout_fraction: float = 0.35) -> Split:
    """Hold a seeded share of the catalogue shapes out of the collection; shared models stay in."""
    catalog = sorted((s for s in shapes if s.from_catalog), key=lambda s: s.source_id)
    order = child_rng(seed, "shape-split").permutation(len(catalog))
    n_held = max(1, round(heldout_fraction * len(catalog)))
    heldout = tuple(catalog[int(i)] for i in order[:n_held])
    held_ids = {s.source_id for s in heldout}
    collection = tuple(s for s in sorted(shapes, key=lambda s: (s.source, s.source_id)) if s.source_id not in held_ids)
    return Split(collection=collection, heldout=heldout)


def substance_hint(part_name: str) -> str | None:
    """The substance a part's own name states, if any (first keyword group that matches)."""
    text = re.sub(r"[^a-z]+", " ", part_name.lower())
    for substance, words in SUBSTANCE_KEYWORDS:
        if any(w in text for w in words):
            return substance
    return None


def _substance(rng: np.random.Generator, part: str) -> str:
    hinted = substance_hint(part)
    if hinted is not None:  # what the model's author meant: a plausible photo
        return hinted
    names = list(FALLBACK_WEIGHTS)
    weights = np.array([FALLBACK_WEIGHTS[n] for n in names])
    return names[int(rng.choice(len(names), p=weights / weights.sum()))]


def draw_variant(rng: np.random.Generator, of: str) -> Variant:
    """A visibly different but same-substance material: hue +-15..40 deg, roughness x0.6..1.5, tile x0.6..1.6."""
    hue = float(rng.uniform(15, 40)) * (1 if rng.random() < 0.5 else -1)
    return Variant(of=of, hue_shift_deg=round(hue, 1), roughness_scale=round(float(rng.uniform(0.6, 1.5)), 2),
                   uv_scale=round(float(rng.uniform(0.6, 1.6)), 2))


def assign_parts(rng: np.random.Generator, parts: tuple[str, ...], library: list[LibraryMaterial],
                 open_library: bool) -> dict[str, PartPlan]:
    """One material per part: a library material of the part's substance (or its variant)."""
    by_substance = {s: [m for m in library if m.substance == s] for s in SUBSTANCES}
    out: dict[str, PartPlan] = {}
    for part in parts:
        substance = _substance(rng, part)
        pool = by_substance[substance] or library
        material = pool[int(rng.integers(len(pool)))]
        variant = draw_variant(rng, material.name) if open_library else None
        out[part] = PartPlan(material.name, material.substance, variant)
    return out


def plan_world(seed: int, split: Split, library: list[LibraryMaterial], envmaps: list[str],
               count: int) -> list[ExemplarPlan]:
    """`count` exemplars; every substance is made to appear (the last exemplars give up a part if not)."""
    if not split.collection or not split.heldout:
        raise ValueError("the world needs both ingested and held-out shapes")
    if not envmaps:
        raise ValueError("the world needs at least one exemplar HDRI")
    coll_order = child_rng(seed, "collection-order").permutation(len(split.collection))
    held_order = child_rng(seed, "heldout-order").permutation(len(split.heldout))
    plans: list[ExemplarPlan] = []
    n_coll = n_held = 0
    for k in range(count):
        rng = child_rng(seed, "exemplar", k)
        if k % 8 in HELDOUT_SHAPE_SLOTS:
            shape, in_collection = split.heldout[int(held_order[n_held % len(held_order)])], False
            n_held += 1
        else:
            shape, in_collection = split.collection[int(coll_order[n_coll % len(coll_order)])], True
            n_coll += 1
        parts = assign_parts(rng, shape.parts, library, k % 7 in OPEN_LIBRARY_SLOTS)
        camera = sample_camera(rng, shape.points)
        envmap = {"name": envmaps[int(rng.integers(len(envmaps)))],
                  "rotation": round(float(rng.uniform(0, 2 * math.pi)), 6),
                  "strength": round(float(rng.uniform(0.8, 1.25)), 4)}
        plans.append(ExemplarPlan(
            stem=f"sw_{k:04d}", shape=shape, in_collection=in_collection, parts=parts, camera=camera,
            envmap=envmap, jpeg_quality=int(rng.integers(80, 96)), render_seed=int(rng.integers(0, 2**31 - 1)),
        ))
    return ensure_substances(seed, plans, library)


def ensure_substances(seed: int, plans: list[ExemplarPlan], library: list[LibraryMaterial]) -> list[ExemplarPlan]:
    """Give each missing substance to one part of a seeded exemplar (one with >= 2 parts), so all five appear."""
    out = list(plans)
    for s_index, substance in enumerate(SUBSTANCES):
        if any(p.substance == substance for plan in out for p in plan.parts.values()):
            continue
        rng = child_rng(seed, "substance-fix", substance)
        pool = [m for m in library if m.substance == substance]
        if not pool:
            raise ValueError(f"the material library has no {substance} material")
        k = (len(out) - 1 - s_index) % len(out)
        plan = out[k]
        part = sorted(plan.shape.parts)[int(rng.integers(len(plan.shape.parts)))]
        material = pool[int(rng.integers(len(pool)))]
        variant = draw_variant(rng, material.name) if plan.open_library else None
        parts = {**plan.parts, part: PartPlan(material.name, substance, variant)}
        out[k] = ExemplarPlan(plan.stem, plan.shape, plan.in_collection, parts, plan.camera, plan.envmap,
                              plan.jpeg_quality, plan.render_seed)
    return out


def world_counts(plans: list[ExemplarPlan]) -> dict[str, Any]:
    """The figures the README and the build report: shares, shapes, substances."""
    n = len(plans)
    shown = {(p.shape.source, p.shape.source_id) for p in plans}
    catalogue = {key for p in plans if p.shape.from_catalog for key in [(p.shape.source, p.shape.source_id)]}
    substances = Counter(part.substance for p in plans for part in p.parts.values())
    return {
        "exemplars": n,
        "shapes_shown": len(shown),
        "catalogue_shapes_shown": len(catalogue),
        "heldout_shape_exemplars": sum(not p.in_collection for p in plans),
        "heldout_shape_share": round(sum(not p.in_collection for p in plans) / n, 3) if n else 0.0,
        "open_library_exemplars": sum(p.open_library for p in plans),
        "open_library_share": round(sum(p.open_library for p in plans) / n, 3) if n else 0.0,
        "parts": sum(len(p.parts) for p in plans),
        "substance_parts": {s: substances.get(s, 0) for s in SUBSTANCES},
    }


def check_world(plans: list[ExemplarPlan]) -> list[str]:
    """What the issue requires of the world and this plan misses (empty when it holds)."""
    counts = world_counts(plans)
    problems = []
    if counts["heldout_shape_share"] < MIN_HELDOUT_SHARE:
        problems.append(f"only {counts['heldout_shape_share']:.2f} of the exemplars show non-ingested shapes")
    if counts["open_library_share"] < MIN_OPEN_LIBRARY_SHARE:
        problems.append(f"only {counts['open_library_share']:.2f} of the exemplars use non-ingested materials")
    missing = [s for s, c in counts["substance_parts"].items() if c == 0]
    if missing:
        problems.append(f"substances never shown: {', '.join(missing)}")
    few = [p.stem for p in plans if len(p.parts) < 2]
    if few:
        problems.append(f"exemplars of shapes with fewer than 2 parts: {', '.join(few)}")
    return problems
