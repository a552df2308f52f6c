"""The demo's sizes: how many shapes, materials, studios and exemplars each preset generates, and
how finely (exemplar size, samples per pixel, texture and envmap resolution)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

DemoSize = Literal["tiny", "small", "medium"]


@dataclass(frozen=True)
class SizePreset:
    shapes: int
    heldout_shapes: int
    per_substance: int
    envmaps: int
    heldout_envmaps: int
    exemplars: int
    exemplar_size: int
    spp: int
    texture_resolution: int = 512
    envmap_width: int = 512


SIZES: dict[str, SizePreset] = {
    "tiny": SizePreset(
        shapes=5,
        heldout_shapes=2,
        per_substance=2,
        envmaps=3,
        heldout_envmaps=2,
        exemplars=6,
        exemplar_size=144,
        spp=24,
        envmap_width=256,
    ),
    "small": SizePreset(
        shapes=12,
        heldout_shapes=4,
        per_substance=3,
        envmaps=4,
        heldout_envmaps=2,
        exemplars=20,
        exemplar_size=256,
        spp=48,
    ),
    "medium": SizePreset(
        shapes=72,
        heldout_shapes=16,
        per_substance=6,
        envmaps=26,  # + 4 held out = the paper's 30 studio envmaps (section 3.3)
        heldout_envmaps=4,
        exemplars=200,
        exemplar_size=320,
        spp=48,
    ),
}
