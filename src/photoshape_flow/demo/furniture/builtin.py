"""The flat built-in material a modeller would have left on each part (Kd colour, no texture)."""

from __future__ import annotations

from typing import Any

import numpy as np

from photoshape_flow.demo.furniture.model import SUBSTANCE_PRIOR, FurniturePart

_BUILTIN_COLOURS: dict[str, list[tuple[float, float, float]]] = {
    "wood": [(0.55, 0.38, 0.22), (0.36, 0.22, 0.13), (0.72, 0.56, 0.38), (0.47, 0.27, 0.17)],
    "metal": [(0.62, 0.62, 0.64), (0.25, 0.25, 0.27), (0.8, 0.8, 0.82)],
    "plastic": [(0.92, 0.92, 0.9), (0.1, 0.1, 0.1), (0.6, 0.1, 0.1), (0.2, 0.3, 0.55)],
    "fabric": [(0.5, 0.5, 0.52), (0.22, 0.28, 0.45), (0.7, 0.64, 0.55), (0.3, 0.42, 0.3), (0.55, 0.18, 0.16)],
    "leather": [(0.32, 0.18, 0.1), (0.08, 0.07, 0.07), (0.6, 0.38, 0.2), (0.88, 0.85, 0.8)],
}
_BUILTIN_BRDF = {
    "wood": (0.6, 0.0),
    "metal": (0.3, 1.0),
    "plastic": (0.35, 0.0),
    "fabric": (0.9, 0.0),
    "leather": (0.5, 0.0),
}


def builtin_material(rng: np.random.Generator, part: FurniturePart) -> dict[str, Any]:
    """A plausible flat material as a modeller would have left it (Kd colour, no texture)."""
    prior = SUBSTANCE_PRIOR[part.prior_key]
    subs = sorted(prior)
    substance = subs[int(rng.choice(len(subs), p=np.array([prior[s] for s in subs]) / sum(prior.values())))]
    colours = _BUILTIN_COLOURS[substance]
    base = np.array(colours[int(rng.integers(len(colours)))])
    colour = np.clip(base * rng.uniform(0.9, 1.1, 3), 0.0, 1.0)
    roughness, metallic = _BUILTIN_BRDF[substance]
    return {
        "albedo": [round(float(c), 4) for c in colour],
        "roughness": roughness,
        "metallic": metallic,
        "name": part.name,
    }
