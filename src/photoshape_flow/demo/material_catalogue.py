"""The demo's material catalogue: a recipe (name, substance, texture scale, pattern parameters) per
material, for the five substances (section 3.3's material collection, in miniature).

Each substance's list is ordered so that its first k recipes are the most distinct: a collection of
size k takes the first k of every substance (`select_recipes`). The maps a recipe yields are
`demo.materials`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from photoshape_flow.vocab import SUBSTANCES


@dataclass(frozen=True)
class MaterialRecipe:
    name: str
    substance: str
    scale: float  # world size of one tile, unit-cube units
    pattern: str
    params: dict[str, Any] = field(default_factory=dict)


def _r(name, substance, scale, pattern, **params) -> MaterialRecipe:
    return MaterialRecipe(name, substance, scale, pattern, params)


CATALOGUE: dict[str, list[MaterialRecipe]] = {
    "wood": [
        _r(
            "wood_oak",
            "wood",
            0.45,
            "wood",
            light=(0.74, 0.56, 0.36),
            dark=(0.52, 0.35, 0.2),
            rings=6,
            sharp=3.0,
            pores=0.35,
            warp=0.6,
            rough=0.55,
        ),
        _r(
            "wood_walnut",
            "wood",
            0.5,
            "wood",
            light=(0.42, 0.28, 0.18),
            dark=(0.2, 0.12, 0.07),
            rings=5,
            sharp=2.0,
            pores=0.15,
            warp=0.9,
            rough=0.45,
        ),
        _r(
            "wood_pine",
            "wood",
            0.55,
            "wood",
            light=(0.88, 0.74, 0.52),
            dark=(0.68, 0.45, 0.24),
            rings=4,
            sharp=6.0,
            pores=0.05,
            warp=0.7,
            rough=0.62,
        ),
        _r(
            "wood_cherry",
            "wood",
            0.45,
            "wood",
            light=(0.68, 0.38, 0.22),
            dark=(0.5, 0.24, 0.13),
            rings=7,
            sharp=2.5,
            pores=0.1,
            warp=0.5,
            rough=0.38,
        ),
        _r(
            "wood_maple",
            "wood",
            0.4,
            "wood",
            light=(0.89, 0.79, 0.63),
            dark=(0.8, 0.67, 0.5),
            rings=9,
            sharp=2.0,
            pores=0.06,
            warp=0.4,
            rough=0.45,
        ),
        _r(
            "wood_ebonised",
            "wood",
            0.45,
            "wood",
            light=(0.2, 0.15, 0.12),
            dark=(0.09, 0.07, 0.06),
            rings=6,
            sharp=2.5,
            pores=0.25,
            warp=0.6,
            rough=0.32,
        ),
    ],
    "leather": [
        _r("leather_brown", "leather", 0.3, "leather", colour=(0.4, 0.22, 0.12), cells=40, creases=0.6, rough=0.5),
        _r("leather_black", "leather", 0.3, "leather", colour=(0.075, 0.07, 0.065), cells=48, creases=0.4, rough=0.35),
        _r("leather_cognac", "leather", 0.3, "leather", colour=(0.68, 0.4, 0.19), cells=36, creases=0.8, rough=0.55),
        _r("leather_cream", "leather", 0.3, "leather", colour=(0.86, 0.82, 0.74), cells=44, creases=0.5, rough=0.45),
        _r("leather_oxblood", "leather", 0.3, "leather", colour=(0.4, 0.09, 0.09), cells=40, creases=0.7, rough=0.45),
        _r("leather_navy", "leather", 0.3, "leather", colour=(0.12, 0.16, 0.3), cells=44, creases=0.5, rough=0.5),
    ],
    "fabric": [
        _r(
            "fabric_grey_weave",
            "fabric",
            0.12,
            "weave",
            warp=(0.54, 0.54, 0.55),
            weft=(0.46, 0.46, 0.48),
            threads=32,
            rough=0.88,
        ),
        _r(
            "fabric_blue_twill",
            "fabric",
            0.12,
            "twill",
            warp=(0.17, 0.24, 0.45),
            weft=(0.25, 0.3, 0.5),
            threads=32,
            rough=0.85,
        ),
        _r(
            "fabric_beige_knit",
            "fabric",
            0.1,
            "knit",
            warp=(0.78, 0.7, 0.58),
            weft=(0.7, 0.62, 0.5),
            threads=24,
            rough=0.92,
        ),
        _r(
            "fabric_green_velvet",
            "fabric",
            0.2,
            "velvet",
            warp=(0.16, 0.32, 0.2),
            weft=(0.1, 0.22, 0.13),
            threads=64,
            rough=0.95,
        ),
        _r(
            "fabric_red_weave",
            "fabric",
            0.12,
            "weave",
            warp=(0.6, 0.14, 0.12),
            weft=(0.55, 0.12, 0.11),
            threads=28,
            rough=0.85,
        ),
        _r(
            "fabric_charcoal_knit",
            "fabric",
            0.1,
            "knit",
            warp=(0.22, 0.22, 0.23),
            weft=(0.3, 0.3, 0.31),
            threads=24,
            rough=0.9,
        ),
    ],
    "metal": [
        _r("metal_brushed_steel", "metal", 0.3, "brushed", colour=(0.78, 0.78, 0.79), rough=0.3, streak=0.08),
        _r("metal_chrome", "metal", 0.3, "polished", colour=(0.96, 0.96, 0.97), rough=0.04, smudge=0.02),
        _r("metal_black_painted", "metal", 0.3, "painted", colour=(0.06, 0.06, 0.065), rough=0.4, peel=1.0),
        _r("metal_polished_aluminium", "metal", 0.3, "polished", colour=(0.91, 0.92, 0.93), rough=0.14, smudge=0.06),
        _r("metal_brass", "metal", 0.3, "brushed", colour=(0.9, 0.76, 0.42), rough=0.22, streak=0.06),
        _r("metal_white_painted", "metal", 0.3, "painted", colour=(0.88, 0.88, 0.86), rough=0.35, peel=1.0),
    ],
    "plastic": [
        _r("plastic_glossy_white", "plastic", 0.3, "plastic", colour=(0.9, 0.9, 0.88), rough=0.12, bumps=0.0),
        _r("plastic_matte_black", "plastic", 0.3, "plastic", colour=(0.07, 0.07, 0.07), rough=0.7, bumps=0.3),
        _r("plastic_textured_grey", "plastic", 0.15, "plastic", colour=(0.45, 0.46, 0.47), rough=0.55, bumps=1.0),
        _r("plastic_glossy_red", "plastic", 0.3, "plastic", colour=(0.72, 0.08, 0.07), rough=0.15, bumps=0.0),
        _r("plastic_matte_beige", "plastic", 0.3, "plastic", colour=(0.8, 0.74, 0.62), rough=0.65, bumps=0.3),
        _r("plastic_glossy_blue", "plastic", 0.3, "plastic", colour=(0.1, 0.25, 0.6), rough=0.18, bumps=0.0),
    ],
}
MAX_PER_SUBSTANCE = min(len(v) for v in CATALOGUE.values())


def select_recipes(per_substance: int) -> list[MaterialRecipe]:
    """The first `per_substance` recipes of every substance, in SUBSTANCES order."""
    if not 1 <= per_substance <= MAX_PER_SUBSTANCE:
        raise ValueError(f"materials per substance must be in 1..{MAX_PER_SUBSTANCE}, got {per_substance}")
    return [r for s in SUBSTANCES for r in CATALOGUE[s][:per_substance]]
