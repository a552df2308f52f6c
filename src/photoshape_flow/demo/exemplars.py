"""Photo-like exemplars with ground truth: held-out renders degraded like product photos.

An exemplar is a demo shape (in the collection or a held-out look-alike) with a material assignment
drawn from the collection under the substance prior, lit by a held-out studio, seen from a product-
photo camera (elevation in [-pi/16, pi/4] like the coarse-alignment rings, any azimuth, fov 50-60,
distance chosen so the object fills the frame), rendered on white, then degraded: exposure and
white-balance jitter, a slight blur, sensor noise and JPEG. Its part mask (exact part ids from the
same camera) is the ground truth for alignment, substance and material evaluation. `plan_exemplars`
decides all of it per exemplar (so a plan can be hashed and skipped); `render_exemplar` renders one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from photoshape_flow.demo.envmaps import StudioSpec
from photoshape_flow.demo.furniture.model import SUBSTANCE_PRIOR, Furniture
from photoshape_flow.demo.material_catalogue import MaterialRecipe
from photoshape_flow.demo.seeding import child_rng
from photoshape_flow.demo.sizes import SizePreset
from photoshape_flow.render.camera import Camera
from photoshape_flow.render.protocol import RendererProtocol
from photoshape_flow.render.specs import EnvmapSpec, MaterialSpec, linear_to_srgb
from photoshape_flow.vocab import SUBSTANCES

ELEVATION_RANGE = (-math.pi / 16, math.pi / 4)
FOV_RANGE = (50.0, 60.0)


@dataclass
class ExemplarPlan:
    """Everything that determines one exemplar (so it can be hashed, skipped or re-rendered)."""

    stem: str
    shape_id: str
    in_collection: bool
    similar_to: str | None
    camera: dict[str, float]
    materials: dict[str, str]  # part name -> material name
    substances: dict[str, str]  # part name -> substance
    envmap: dict[str, Any]  # name, rotation, scale
    degradation: dict[str, Any]
    size: int
    spp: int
    render_seed: int


# -- camera ---------------------------------------------------------------------------------------


def framing_distance(vertices: np.ndarray, azimuth: float, elevation: float, fov: float, fill: float) -> float:
    """The camera distance at which the projected shape spans `fill` of the half-frame (max |x|, |y|)."""
    pts = np.asarray(vertices, np.float64)
    lo, hi = 0.6, 20.0

    def extent(d: float) -> float:
        xy, depth = Camera(azimuth, elevation, d, fov).project(pts, 2)
        if (depth <= 1e-3).any():
            return np.inf
        return float(np.abs(xy - 1.0).max())

    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if extent(mid) > fill:
            lo = mid
        else:
            hi = mid
    return hi


def sample_camera(rng: np.random.Generator, vertices: np.ndarray) -> dict[str, float]:
    """A product-photo camera: any azimuth, elevation in the coarse-alignment range, fov 50-60."""
    azimuth = float(rng.uniform(0.0, 2 * math.pi))
    elevation = float(rng.uniform(*ELEVATION_RANGE))
    fov = float(rng.uniform(*FOV_RANGE))
    fill = float(rng.uniform(0.8, 0.94))
    distance = framing_distance(vertices, azimuth, elevation, fov, fill)
    return {"azimuth": azimuth, "elevation": elevation, "distance": round(distance, 6), "fov": fov}


# -- materials ------------------------------------------------------------------------------------


def _slot(part, share_soft: bool, share_structure: bool) -> str:
    """Parts in one slot get one material: upholstery usually matches, as do legs and frame."""
    roles = part.roles
    if part.soft:
        return "soft" if share_soft else "soft:" + "+".join(roles)
    if share_structure and set(roles) & {"legs", "frame"} and not set(roles) & {"seat", "back", "base", "casters"}:
        return "structure"
    return "+".join(roles)


def assign_materials(
    rng: np.random.Generator, furniture: Furniture, recipes: dict[str, list[MaterialRecipe]]
) -> dict[str, MaterialRecipe]:
    """A material for every part, substances drawn from the per-role prior (section 5.1's substance prior)."""
    share_soft = bool(rng.random() < 0.75)
    share_structure = bool(rng.random() < 0.7)
    chosen: dict[str, MaterialRecipe] = {}
    out: dict[str, MaterialRecipe] = {}
    for part in furniture.parts:
        slot = _slot(part, share_soft, share_structure)
        if slot not in chosen:
            prior = {s: w for s, w in SUBSTANCE_PRIOR[part.prior_key].items() if recipes.get(s)}
            subs = sorted(prior)
            weights = np.array([prior[s] for s in subs], np.float64)
            substance = subs[int(rng.choice(len(subs), p=weights / weights.sum()))]
            options = recipes[substance]
            chosen[slot] = options[int(rng.integers(len(options)))]
        out[part.name] = chosen[slot]
    return out


# -- degradation ----------------------------------------------------------------------------------


def sample_degradation(rng: np.random.Generator) -> dict[str, Any]:
    """Photo imperfections: exposure, white balance, background level, blur, noise, JPEG quality."""
    gains = np.exp(rng.normal(0.0, 0.04, 3))
    gains = gains / float(gains @ np.array([0.2126, 0.7152, 0.0722]))
    return {
        "exposure": round(float(rng.uniform(0.75, 1.15)), 4),
        "white_balance": [round(float(g), 4) for g in gains],
        "background": round(float(rng.uniform(0.97, 1.06)), 4),
        "blur_sigma": round(float(rng.uniform(0.3, 0.9)), 4),
        "noise_sigma": round(float(rng.uniform(0.5, 2.5)), 4),  # in 8-bit levels
        "jpeg_quality": int(rng.integers(72, 93)),
        "noise_seed": int(rng.integers(0, 2**31 - 1)),
    }


def degrade(premultiplied: np.ndarray, alpha: np.ndarray, params: dict[str, Any]) -> np.ndarray:
    """An 8-bit RGB 'photo' from a premultiplied linear render and its coverage."""
    gains = np.asarray(params["white_balance"], np.float64) * float(params["exposure"])
    a = np.clip(alpha, 0.0, 1.0)[..., None].astype(np.float64)
    background = float(params["background"]) * np.asarray(params["white_balance"], np.float64)
    # clamp fireflies (rare paths that hit a soft box) before the blur spreads them into blobs
    linear = np.minimum(premultiplied.astype(np.float64), 2.0) * gains + (1.0 - a) * background
    sigma = float(params["blur_sigma"])
    if sigma > 0:
        linear = cv2.GaussianBlur(linear, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REPLICATE)
    srgb = linear_to_srgb(linear) * 255.0
    noise_rng = np.random.default_rng(int(params["noise_seed"]))
    srgb = srgb + noise_rng.normal(0.0, float(params["noise_sigma"]), srgb.shape)
    return np.clip(np.round(srgb), 0, 255).astype(np.uint8)


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def encode_mask(mask: np.ndarray) -> bytes:
    """PNG of part indices: uint8 when they fit, else uint16."""
    data = mask.astype(np.uint8) if int(mask.max(initial=0)) < 256 else mask.astype(np.uint16)
    ok, buf = cv2.imencode(".png", data)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


# -- planning and rendering -----------------------------------------------------------------------


def plan_exemplars(
    seed: int,
    preset: SizePreset,
    collection: list[Furniture],
    heldout: list[tuple[Furniture, str]],
    recipes: list[MaterialRecipe],
    studios: list[StudioSpec],
) -> list[ExemplarPlan]:
    """Which shape, materials, camera, light and degradation each exemplar gets.

    Two in five exemplars show a held-out shape (retrieval can only find a similar one); the others
    show a collection shape. Material assignments never repeat for the same shape.
    """
    by_substance: dict[str, list[MaterialRecipe]] = {s: [r for r in recipes if r.substance == s] for s in SUBSTANCES}
    order = child_rng(seed, "exemplar-order").permutation(len(collection))
    used: set[tuple] = set()
    plans = []
    n_coll = n_held = 0
    for k in range(preset.exemplars):
        rng = child_rng(seed, "exemplar", k)
        if heldout and k % 5 in (1, 3):
            furniture, similar_to = heldout[n_held % len(heldout)]
            in_collection = False
            n_held += 1
        else:
            furniture, similar_to = collection[int(order[n_coll % len(collection)])], None
            in_collection = True
            n_coll += 1
        vertices = np.concatenate([c.piece.vertices for p in furniture.parts for c in p.components])
        camera = sample_camera(rng, vertices)
        for _ in range(50):
            assignment = assign_materials(rng, furniture, by_substance)
            key = (furniture.source_id, tuple(sorted((n, r.name) for n, r in assignment.items())))
            if key not in used:
                break
        used.add(key)
        studio = studios[int(rng.integers(len(studios)))]
        plans.append(
            ExemplarPlan(
                stem=f"ex_{k:04d}",
                shape_id=furniture.source_id,
                in_collection=in_collection,
                similar_to=similar_to,
                camera=camera,
                materials={n: r.name for n, r in assignment.items()},
                substances={n: r.substance for n, r in assignment.items()},
                envmap={
                    "name": studio.name,
                    "rotation": round(float(rng.uniform(0, 2 * math.pi)), 6),
                    "scale": round(float(rng.uniform(0.9, 1.2)), 4),
                },
                degradation=sample_degradation(rng),
                size=preset.exemplar_size,
                spp=preset.spp,
                render_seed=int(rng.integers(0, 2**31 - 1)),
            )
        )
    return plans


def _material_spec(folder: Path, recipe: MaterialRecipe):
    maps = {ch: folder / f"{ch}.png" for ch in ("albedo", "roughness", "metallic", "normal")}
    return MaterialSpec(name=recipe.name, substance=recipe.substance, maps=maps, scale=recipe.scale)


def render_exemplar(
    renderer: RendererProtocol,
    furniture: Furniture,
    plan: ExemplarPlan,
    material_dirs: dict[str, Path],
    recipes: dict[str, MaterialRecipe],
    envmap_path: Path,
) -> tuple[bytes, np.ndarray]:
    """(JPEG bytes, part-index mask) of one planned exemplar."""
    shape = furniture.to_shape_mesh()
    camera = Camera.from_dict(plan.camera)
    materials = [
        _material_spec(material_dirs[plan.materials[p.name]], recipes[plan.materials[p.name]]) for p in shape.parts
    ]
    envmap = EnvmapSpec(envmap_path, scale=plan.envmap["scale"], rotation=plan.envmap["rotation"])
    result = renderer.beauty(
        shape, materials, camera, envmap, size=plan.size, spp=plan.spp, background="transparent", seed=plan.render_seed,
        record=False,  # one render per photo, each its own seed: nothing to replay
    )
    image = degrade(result.hdr, result.alpha, plan.degradation)
    mask = renderer.part_ids(shape, camera, size=plan.size)
    return encode_jpeg(image, plan.degradation["jpeg_quality"]), mask
