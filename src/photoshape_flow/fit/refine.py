"""Refine the fit's winners: a few parameters per part, fitted to the photo by rendering (issue 26 item 5).

The library holds a finite set of materials; the photo's is usually a little lighter, warmer,
glossier or more finely patterned than the nearest one. So each refined part keeps its chosen
material and fits four numbers (a `render.specs.Refinement`), never texels:

- **UV scale and rotation** by a small search of forward renders (`uv_search`): Mitsuba's UV
  transform has no gradients, and the loss is periodic in both. Every grid point is one render with
  every textured part at that point; each part keeps its own best, compared with the photo by
  texture statistics that tolerate misalignment (the fit's gradient and contrast terms plus the
  structure-tensor orientation, which the gradient magnitude cannot see). Identity wins ties
  within `uv_margin`, so an untextured or isotropic material is not rotated at random.
- **Albedo tint** (3 values, log space) and **roughness scale** (log space) by Adam on Mitsuba's
  ``llvm_ad_rgb`` gradients (`render.gradients.GradientScene`), clamped to `tint_range` and
  `roughness_range`. The loss is per part, over the rendered part's eroded region: the relative L2
  of the mean linear colour after the stage's exposure against the photo region's mean, plus
  `std_weight` x the same for the per-channel standard deviation (the light structural term:
  highlights and texture contrast, which roughness moves). Region statistics, not pixels, for the
  reason of docs/decisions.md D32: alignment is off by a few pixels. A new seed every iteration,
  low spp: Adam averages the noise.

All parts are refined in the same renders. `refine_parts` returns, per part, the refinement and the
loss before and after (both at seed 0, so the noise is the same).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from photoshape_flow.fit import lighting as lt
from photoshape_flow.fit.appearance import Weights, appearance, distance, erode, to_lab
from photoshape_flow.render.specs import Refinement

TEXTURED = ("albedo", "roughness", "normal")  # maps whose placement the UV transform moves


@dataclass(frozen=True)
class RefineSettings:
    """How hard to refine (the `FitConfig` refine fields)."""

    iterations: int = 24
    spp: int = 4
    learning_rate: float = 0.08
    tint_range: tuple[float, float] = (0.5, 2.0)
    roughness_range: tuple[float, float] = (0.5, 2.0)
    std_weight: float = 0.25
    uv_scales: tuple[float, ...] = (0.5, 0.7, 1.0, 1.4, 2.0)
    uv_rotations: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0)  # degrees
    uv_margin: float = 0.03  # a UV hypothesis must beat identity by this fraction of its cost
    orientation_weight: float = 1.0
    max_depth: int = 3
    erode: int = 1


@dataclass
class PartRefinement:
    """One part's fitted refinement and its loss (the `refine_parts` loss) before and after."""

    refinement: Refinement
    loss_before: float
    loss_after: float
    uv_cost: dict[str, float] = field(default_factory=dict)  # "identity", "chosen": the search's costs

    def to_dict(self) -> dict[str, Any]:
        return {**self.refinement.to_dict(), "loss_before": round(self.loss_before, 6),
                "loss_after": round(self.loss_after, 6),
                **({"uv_cost": {k: round(v, 6) for k, v in self.uv_cost.items()}} if self.uv_cost else {})}


# -- pure pieces -----------------------------------------------------------------------------------------
def region_targets(linear: np.ndarray, masks: Mapping[int, np.ndarray]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per region: (mean, std) of linear RGB, what the rendered region is fitted to."""
    out = {}
    for index, mask in masks.items():
        pixels = np.asarray(linear)[np.asarray(mask, bool)].reshape(-1, 3).astype(np.float64)
        if len(pixels):
            out[index] = (pixels.mean(axis=0), pixels.std(axis=0))
    return out


def region_loss(mean: np.ndarray, std: np.ndarray, target: tuple[np.ndarray, np.ndarray], exposure: float,
                std_weight: float) -> float:
    """The refinement loss of one region given its rendered statistics (NumPy twin of the Dr.Jit loss)."""
    t_mean, t_std = target
    level = t_mean + 0.02
    return float(np.mean(((exposure * mean - t_mean) / level) ** 2)
                 + std_weight * np.mean(((exposure * std - t_std) / level) ** 2))


def orientation(lab: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The region's dominant texture orientation as a doubled-angle vector in the unit disc.

    From the structure tensor of L* (mean gx^2, gy^2, gx gy over the region): ((Jxx - Jyy), 2 Jxy) /
    (Jxx + Jyy). Length 0: no preferred direction; rotating the texture by t turns it by 2t.
    """
    lightness = np.ascontiguousarray(lab[..., 0], np.float32)
    mask = np.asarray(mask, bool)
    if not mask.any():
        return np.zeros(2)
    filled = np.where(mask, lightness, np.float32(lightness[mask].mean()))
    gx = cv2.Sobel(filled, cv2.CV_32F, 1, 0, ksize=3)[mask].astype(np.float64)
    gy = cv2.Sobel(filled, cv2.CV_32F, 0, 1, ksize=3)[mask].astype(np.float64)
    jxx, jyy, jxy = (gx * gx).mean(), (gy * gy).mean(), (gx * gy).mean()
    total = jxx + jyy
    return np.zeros(2) if total <= 1e-9 else np.array([jxx - jyy, 2.0 * jxy]) / total


def choose_uv(costs: Mapping[tuple[float, float], float], margin: float) -> tuple[float, float]:
    """The (scale, rotation) of lowest cost; identity (1, 0) unless that beats it by `margin` of its cost."""
    best = min(costs, key=lambda k: (costs[k], abs(math.log(k[0])), k[1]))
    identity = (1.0, 0.0)
    if identity in costs and costs[best] > (1.0 - margin) * costs[identity]:
        return identity
    return best


def log_range(bounds: tuple[float, float]) -> tuple[float, float]:
    """A multiplier's range in log space, where Adam steps it (equal steps up and down)."""
    return math.log(bounds[0]), math.log(bounds[1])


def is_textured(spec: Any) -> bool:
    return spec is not None and any(k in (getattr(spec, "maps", None) or {}) for k in TEXTURED)


def with_refinement(spec: Any, refinement: Refinement | None) -> Any:
    return spec if spec is None else dataclasses.replace(spec, refinement=refinement)


# -- the render loops ------------------------------------------------------------------------------------
def uv_search(frame: Any, scene: Any, materials: Sequence[Any], parts: Sequence[int], envmap: Any,
              exposure: float, settings: RefineSettings) -> dict[int, tuple[tuple[float, float], dict[str, float]]]:
    """Per textured part of `parts`: ((scale, rotation radians), {"identity": cost, "chosen": cost}).

    `scene` is the pair's `fit.scene.FitScene` (its photo and regions) at `frame`'s size; one render
    per grid point, with every textured part at that point.
    """
    positions = {p.index: k for k, p in enumerate(scene.mesh.parts)}
    textured = [i for i in parts if i in positions and is_textured(materials[positions[i]])
                and i in scene.photo_stats]
    if not textured:
        return {}
    ids = frame.part_ids(scene.mesh, scene.camera)
    regions = {i: erode(ids == i, settings.erode) for i in textured}
    photo_lab = scene.photo_lab
    photo_orientation = {i: orientation(photo_lab, scene.masks[i]) for i in textured}
    weights = Weights(color=0.0, contrast=0.5, gradient=1.0)
    costs: dict[int, dict[tuple[float, float], float]] = {i: {} for i in textured}
    for scale in settings.uv_scales:
        for degrees in settings.uv_rotations:
            point = (float(scale), math.radians(degrees))
            trial = list(materials)
            for i in textured:
                trial[positions[i]] = with_refinement(materials[positions[i]], Refinement(uv_scale=point[0],
                                                                                          uv_rotation=point[1]))
            lab = to_lab(lt.exposed_srgb(scene.render(frame, trial, envmap), exposure))
            for i in textured:
                rendered = appearance(lab, regions[i])
                if rendered is None:
                    continue
                cost = distance(rendered, scene.photo_stats[i], weights) + settings.orientation_weight * float(
                    np.linalg.norm(orientation(lab, regions[i]) - photo_orientation[i]))
                costs[i][point] = cost
    out = {}
    for i, by_point in costs.items():
        if by_point:
            chosen = choose_uv(by_point, settings.uv_margin)
            out[i] = (chosen, {"identity": by_point.get((1.0, 0.0), math.nan), "chosen": by_point[chosen]})
    return out


def _statistics(dr: Any, mi: Any, image: Any, weights: Any) -> tuple[list[Any], list[Any]]:
    """Per-channel weighted mean and std of an (H, W, 4) TensorXf, as Dr.Jit Floats (differentiable)."""
    flat = image.array
    pixels = dr.width(weights)
    index = dr.arange(mi.UInt32, pixels) * 4
    means, stds = [], []
    for channel in range(3):
        values = dr.gather(mi.Float, flat, index + channel)
        mean = dr.sum(values * weights)
        second = dr.sum(values * values * weights)
        means.append(mean)
        stds.append(dr.sqrt(dr.maximum(second - mean * mean, 1e-10)))
    return means, stds


def _loss(dr: Any, mi: Any, image: Any, weights: Mapping[int, Any],
          targets: Mapping[int, tuple[np.ndarray, np.ndarray]], shares: Mapping[int, float], exposure: float,
          std_weight: float) -> tuple[Any, dict[int, float]]:
    """(total loss, per-part loss) of a render: `region_loss` of every part, weighted by pixel share."""
    total = mi.Float(0.0)
    per_part = {}
    for index, w in weights.items():
        means, stds = _statistics(dr, mi, image, w)
        t_mean, t_std = targets[index]
        level = t_mean + 0.02
        part = mi.Float(0.0)
        for c in range(3):
            part += dr.square((exposure * means[c] - float(t_mean[c])) / float(level[c])) / 3.0
            part += std_weight * dr.square((exposure * stds[c] - float(t_std[c])) / float(level[c])) / 3.0
        total += shares[index] * part
        per_part[index] = part
    dr.eval(total)
    return total, {i: float(v.array[0] if hasattr(v, "array") else v[0]) for i, v in per_part.items()}


def refine_parts(frame: Any, scene: Any, materials: Sequence[Any], parts: Sequence[int], envmap: Any,
                 exposure: float, settings: RefineSettings = RefineSettings(),
                 uv_frame: Any = None) -> dict[int, PartRefinement]:
    """Refine the materials of `parts` (part indices; `materials[i]` is `scene.mesh.parts[i]`'s spec).

    `frame` renders the gradient loop (its own size: the statistics do not need the fit's), `uv_frame`
    the UV search at `scene`'s size (default `frame`). Parts without a material (built-in), without a
    photo region or without rendered pixels are left out.
    """
    import drjit as dr

    mesh = scene.mesh
    positions = {p.index: k for k, p in enumerate(mesh.parts)}
    parts = [i for i in parts if i in positions and materials[positions[i]] is not None and i in scene.masks]
    if not parts:
        return {}
    targets = region_targets(scene.photo_linear, {i: scene.masks[i] for i in parts})
    uv = uv_search(uv_frame or frame, scene, materials, parts, envmap, exposure, settings)
    placed = list(materials)
    for i, ((scale, rotation), _) in uv.items():
        placed[positions[i]] = with_refinement(materials[positions[i]], Refinement(uv_scale=scale,
                                                                                    uv_rotation=rotation))
    ids = frame.render_ids(mesh, scene.camera)
    regions = {i: erode(ids == i, settings.erode) for i in parts}
    parts = [i for i in parts if regions[i].sum() >= 4 and i in targets]
    if not parts:
        return {}
    with frame.gradient_scene(mesh, placed, scene.camera, envmap, settings.max_depth) as g:
        mi = g.mi
        total_pixels = sum(float(regions[i].sum()) for i in parts)
        weights = {i: mi.Float((regions[i].ravel() / regions[i].sum()).astype(np.float32)) for i in parts}
        shares = {i: float(regions[i].sum()) / total_pixels for i in parts}
        opt = mi.ad.Adam(lr=settings.learning_rate)
        for i in parts:
            opt[f"tint_{i}"] = mi.Color3f(0.0)
            opt[f"rough_{i}"] = mi.Float(0.0)

        def render(seed: int) -> Any:
            tints = {positions[i]: dr.exp(opt[f"tint_{i}"]) for i in parts}
            rough = {positions[i]: dr.exp(opt[f"rough_{i}"]) for i in parts}
            return g.render(tints, rough, settings.spp, seed)

        before: dict[int, float] = {}
        for iteration in range(max(1, settings.iterations)):
            total, per_part = _loss(dr, mi, render(iteration), weights, targets, shares, exposure,
                                    settings.std_weight)
            if iteration == 0:
                before = per_part
            dr.backward(total)
            opt.step()
            for i in parts:
                opt[f"tint_{i}"] = dr.clip(opt[f"tint_{i}"], *log_range(settings.tint_range))
                opt[f"rough_{i}"] = dr.clip(opt[f"rough_{i}"], *log_range(settings.roughness_range))
        with dr.suspend_grad():
            _, after = _loss(dr, mi, render(0), weights, targets, shares, exposure, settings.std_weight)
        out = {}
        for i in parts:
            tint = tuple(round(float(math.exp(t)), 6) for t in np.array(opt[f"tint_{i}"], np.float64).reshape(-1)[:3])
            rough = round(float(math.exp(float(np.array(opt[f"rough_{i}"]).reshape(-1)[0]))), 6)
            (scale, rotation), uv_cost = uv.get(i, ((1.0, 0.0), {}))
            out[i] = PartRefinement(Refinement(tint, rough, scale, rotation),  # type: ignore[arg-type]
                                    before[i], after[i], uv_cost)
    return out
