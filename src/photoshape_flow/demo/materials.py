"""Procedural, tileable SVBRDFs for the five substances (section 3.3's material collection, in miniature).

Each material is a recipe of `demo.material_catalogue` (name, substance, texture scale, pattern
parameters); this module turns one into its maps and material folder. Maps: albedo (sRGB),
roughness, metallic (linear), height and OpenGL normal derived from it. All patterns come from
`noise` and are periodic, so tiles wrap seamlessly.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from photoshape_flow.demo import noise
from photoshape_flow.demo.material_catalogue import MaterialRecipe
from photoshape_flow.demo.seeding import child_rng
from photoshape_flow.demo.writing import write_bytes

MAP_CHANNELS: tuple[str, ...] = ("albedo", "roughness", "metallic", "normal", "height")


@dataclass
class MaterialMaps:
    albedo: np.ndarray  # (n, n, 3) sRGB in [0, 1]
    roughness: np.ndarray  # (n, n) in [0, 1]
    metallic: np.ndarray  # (n, n) in [0, 1]
    height: np.ndarray  # (n, n) in [0, 1]
    normal: np.ndarray  # (n, n, 3) unit vectors, OpenGL convention


# -- patterns -------------------------------------------------------------------------------------


def _lerp(a, b, t: np.ndarray) -> np.ndarray:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return a + (b - a) * t[..., None]


def _tint(rng: np.random.Generator, colour, amount: float = 0.04) -> np.ndarray:
    """A slightly different shade per seed so collections with different seeds are not identical."""
    return np.clip(np.asarray(colour) * (1 + rng.uniform(-amount, amount, 3)), 0, 1)


def _wood(rng, n, p):
    u, _ = noise.grid(n)
    warp = noise.spectral(rng, n, beta=3.0, fmin=1, fmax=6, stretch=(1.0, 6.0))
    phase = p["rings"] * u + p["warp"] * warp
    x = phase - np.floor(phase)  # earlywood grows slowly into latewood, then an abrupt ring boundary
    late = x ** p["sharp"] * np.clip((1.0 - x) * 25.0, 0, 1)
    fibre = noise.spectral(rng, n, beta=1.0, fmin=6, stretch=(1.0, 20.0))
    pores = noise.normalise01(noise.spectral(rng, n, beta=0.5, fmin=24, stretch=(1.0, 14.0)))
    pores = np.clip((pores - 0.55) * 3.0, 0, 1)
    var = noise.spectral(rng, n, beta=2.5, fmin=1, fmax=8)
    t = np.clip(0.7 * late + p["pores"] * pores + 0.12 * var + 0.06 * fibre, 0, 1)
    albedo = _lerp(_tint(rng, p["light"]), _tint(rng, p["dark"]), t)
    rough = np.clip(p["rough"] + 0.06 * late + 0.1 * pores - 0.03 * var, 0.05, 1)
    height = noise.normalise01(-0.7 * pores - 0.25 * late + 0.05 * var + 0.1 * fibre)
    return albedo, rough, np.zeros((n, n)), height, 4.0


def _leather(rng, n, p):
    d1, d2 = noise.cellular(rng, n, p["cells"])
    pebble = np.clip(1.0 - d1 / 0.8, 0, 1) ** 0.7
    edges = np.exp(-(((d2 - d1) / 0.08) ** 2))  # valleys between pebbles
    crease = noise.ridged(noise.spectral(rng, n, beta=1.5, fmin=3, fmax=24, stretch=(1.0, 2.5), angle=0.6), 10.0)
    crease2 = noise.ridged(noise.spectral(rng, n, beta=1.5, fmin=2, fmax=16), 14.0)
    creases = np.clip(p["creases"] * (crease + 0.6 * crease2), 0, 1)
    mottle = noise.spectral(rng, n, beta=3.0, fmin=1, fmax=6)
    base = _tint(rng, p["colour"])
    shade = np.clip(1.0 + 0.07 * mottle - 0.18 * edges - 0.3 * creases, 0.3, 1.3)
    albedo = np.clip(base[None, None] * shade[..., None], 0, 1)
    rough = np.clip(p["rough"] + 0.12 * edges + 0.15 * creases - 0.08 * pebble, 0.05, 1)
    height = noise.normalise01(0.4 * pebble - 0.4 * edges - 1.0 * creases)
    return albedo, rough, np.zeros((n, n)), height, 14.0


def _thread_profile(x: np.ndarray) -> np.ndarray:
    """Round thread cross-section: 1 at the thread centre (x = 0.5), 0 at its edges."""
    return np.sqrt(np.clip(1.0 - (2 * x - 1) ** 2, 0, 1))


def _fabric(rng, n, p, pattern: str):
    u, v = noise.grid(n)
    k = p["threads"]
    uu, vv = u * k, v * k
    fu, fv = np.floor(uu), np.floor(vv)
    xu, xv = uu - fu, vv - fv
    fibre = noise.spectral(rng, n, beta=0.3, fmin=n / 8, stretch=(1.0, 1.0))
    if pattern == "weave":
        over = (fu + fv) % 2 == 0  # warp over weft on a checkerboard
        warp_h = _thread_profile(xu) * (0.7 + 0.3 * np.cos(np.pi * (xv - 0.5)))
        weft_h = _thread_profile(xv) * (0.7 + 0.3 * np.cos(np.pi * (xu - 0.5)))
    elif pattern == "twill":
        over = (fu + fv) % 4 < 2  # 2/2 twill: diagonal ribs
        warp_h = _thread_profile(xu)
        weft_h = _thread_profile(xv)
    elif pattern == "knit":
        # columns of V-shaped stitches: the stitch coordinate bends with |x - 0.5|
        y = vv + 0.8 * np.abs(xu - 0.5)
        stitch = _thread_profile(y - np.floor(y)) * _thread_profile(np.clip(xu * 0.9 + 0.05, 0, 1)) ** 0.5
        over = np.zeros_like(uu, dtype=bool)
        warp_h = stitch
        weft_h = stitch * 0.6
    elif pattern == "velvet":
        pile = noise.spectral(rng, n, beta=2.5, fmin=1, fmax=10)  # crushed-pile light and dark patches
        over = pile > 0
        warp_h = 0.5 + 0.1 * fibre
        weft_h = 0.5 + 0.1 * fibre
    else:
        raise ValueError(f"unknown fabric pattern {pattern!r}")
    h = np.where(over, np.maximum(warp_h, 0.6 * weft_h), np.maximum(weft_h, 0.6 * warp_h))
    t = over.astype(np.float64)
    if pattern == "velvet":
        t = noise.normalise01(noise.spectral(rng, n, beta=2.5, fmin=1, fmax=10))
    albedo = _lerp(_tint(rng, p["weft"]), _tint(rng, p["warp"]), t)
    shade = np.clip(0.8 + 0.25 * h + 0.04 * fibre, 0.5, 1.2) if pattern != "velvet" else 1.0 + 0.05 * fibre
    albedo = np.clip(albedo * np.asarray(shade)[..., None], 0, 1)
    rough = np.clip(p["rough"] - 0.05 * h + 0.02 * fibre, 0.05, 1)
    height = noise.normalise01(h + 0.05 * fibre)
    return albedo, rough, np.zeros((n, n)), height, 10.0 if pattern != "velvet" else 2.0


def _metal(rng, n, p, pattern: str):
    base = _tint(rng, p["colour"], 0.02)
    if pattern == "brushed":
        streaks = noise.spectral(rng, n, beta=1.0, fmin=2, stretch=(40.0, 1.0))
        scratches = noise.ridged(noise.spectral(rng, n, beta=1.0, fmin=4, stretch=(25.0, 1.0), angle=0.03), 12.0)
        shade = 1.0 + p["streak"] * streaks - 0.05 * scratches
        rough = np.clip(p["rough"] + 0.05 * streaks + 0.05 * scratches, 0.02, 1)
        height = noise.normalise01(streaks - 0.5 * scratches)
        metallic, strength = np.ones((n, n)), 1.5
    elif pattern == "polished":
        smudge = noise.spectral(rng, n, beta=3.0, fmin=1, fmax=8)
        shade = 1.0 - 0.01 * np.abs(smudge)
        rough = np.clip(p["rough"] + p["smudge"] * np.clip(smudge, 0, None), 0.02, 1)
        height = noise.normalise01(smudge)
        metallic, strength = np.ones((n, n)), 0.2
    elif pattern == "painted":
        peel = noise.spectral(rng, n, beta=2.0, fmin=8, fmax=60)  # orange-peel of spray paint
        shade = 1.0 + 0.02 * peel
        rough = np.clip(p["rough"] + 0.04 * peel, 0.02, 1)
        height = noise.normalise01(peel)
        metallic, strength = np.zeros((n, n)), 1.0 * p["peel"]
    else:
        raise ValueError(f"unknown metal pattern {pattern!r}")
    albedo = np.clip(base[None, None] * np.asarray(shade)[..., None], 0, 1)
    return albedo, rough, metallic, height, strength


def _plastic(rng, n, p):
    base = _tint(rng, p["colour"], 0.03)
    stipple_d, _ = noise.cellular(rng, n, 64)
    stipple = np.clip(1.0 - stipple_d / 0.7, 0, 1) ** 2
    wave = noise.spectral(rng, n, beta=3.0, fmin=1, fmax=6)
    h = p["bumps"] * stipple + 0.05 * wave
    albedo = np.clip(base[None, None] * (1.0 + 0.01 * wave - 0.04 * p["bumps"] * stipple)[..., None], 0, 1)
    rough = np.clip(p["rough"] + 0.1 * p["bumps"] * (stipple - 0.5) + 0.01 * wave, 0.02, 1)
    return albedo, rough, np.zeros((n, n)), noise.normalise01(h), 8.0 * p["bumps"] + 0.2


def generate_maps(recipe: MaterialRecipe, seed: int, resolution: int = 512) -> MaterialMaps:
    """The maps of one material (deterministic in seed and recipe name)."""
    rng = child_rng(seed, "material", recipe.name)
    n = resolution
    p = recipe.params
    if recipe.pattern == "wood":
        out = _wood(rng, n, p)
    elif recipe.pattern == "leather":
        out = _leather(rng, n, p)
    elif recipe.pattern in ("weave", "twill", "knit", "velvet"):
        out = _fabric(rng, n, p, recipe.pattern)
    elif recipe.pattern in ("brushed", "polished", "painted"):
        out = _metal(rng, n, p, recipe.pattern)
    elif recipe.pattern == "plastic":
        out = _plastic(rng, n, p)
    else:
        raise ValueError(f"unknown pattern {recipe.pattern!r} in material {recipe.name}")
    albedo, rough, metallic, height, tilt_deg = out
    # bump strength: scale the height slopes so the RMS normal tilt is tilt_deg (resolution independent)
    gx = (np.roll(height, -1, 1) - np.roll(height, 1, 1)) * 0.5
    gy = (np.roll(height, -1, 0) - np.roll(height, 1, 0)) * 0.5
    rms = float(np.sqrt((gx**2 + gy**2).mean()))
    strength = np.tan(np.radians(tilt_deg)) / rms if rms > 0 else 0.0
    normal = noise.normal_from_height(height, strength)
    return MaterialMaps(
        albedo=np.asarray(albedo, np.float64),
        roughness=np.asarray(rough, np.float64),
        metallic=np.asarray(metallic, np.float64),
        height=np.asarray(height, np.float64),
        normal=normal,
    )


# -- files ----------------------------------------------------------------------------------------


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def encode_maps(maps: MaterialMaps) -> dict[str, bytes]:
    """PNG bytes per channel: 8-bit albedo / roughness / metallic / normal, 16-bit height."""
    to8 = lambda x: np.clip(np.round(x * 255.0), 0, 255).astype(np.uint8)  # noqa: E731
    return {
        "albedo": _png(to8(maps.albedo)[..., ::-1]),
        "roughness": _png(to8(maps.roughness)),
        "metallic": _png(to8(maps.metallic)),
        "normal": _png(to8((maps.normal + 1.0) * 0.5)[..., ::-1]),
        "height": _png(np.clip(np.round(maps.height * 65535.0), 0, 65535).astype(np.uint16)),
    }


def sidecar(recipe: MaterialRecipe, seed: int) -> dict[str, Any]:
    """The material.json content (contributing.md format)."""
    return {
        "name": recipe.name,
        "substance": recipe.substance,
        "scale": recipe.scale,
        "normal": "gl",
        "source": "photoshape_flow demo",
        "license": "CC0-1.0",
        "attribution": f"procedurally generated by photoshape_flow demo ({recipe.pattern} pattern, seed {seed})",
        "source_url": None,
    }


def write_material(folder: Path, recipe: MaterialRecipe, seed: int, resolution: int = 512) -> dict[str, Path]:
    """Generate and write one material folder; returns {channel: path}. Unchanged files are not rewritten."""
    folder.mkdir(parents=True, exist_ok=True)
    maps = generate_maps(recipe, seed, resolution)
    paths: dict[str, Path] = {}
    for channel, data in encode_maps(maps).items():
        path = folder / f"{channel}.png"
        write_bytes(path, data)
        paths[channel] = path
    write_bytes(folder / "material.json", (json.dumps(sidecar(recipe, seed), indent=2) + "\n").encode())
    return paths
