"""Refine the fit's winners: a few parameters per part, fitted to the photo by rendering (issue 26 item 5).

The library holds a finite set of materials; the photo's is usually a little lighter, warmer,
glossier or more finely patterned than the nearest one. So each refined part keeps its chosen
material and fits four numbers (a `render.specs.Refinement`), never texels:

The stage fits only the tint by default (`FitConfig.refine_uv` and `refine_iterations` turn the UV
search and the roughness steps on): on validation renders both relit worse (docs/decisions.md D67).

- **UV scale and rotation** by a small search of forward renders (`uv_search`): Mitsuba's UV
  transform has no gradients, and the loss is periodic in both. A coordinate search: every scale
  unrotated, then every rotation at each part's best scale (5 + 3 renders for the default grid,
  not 5 x 4), each render with every textured part at its point; each part keeps its own best,
  compared with the photo by texture statistics that tolerate misalignment (the fit's gradient
  and contrast terms plus the structure-tensor orientation, which the gradient magnitude does not
  measure; on the two-box test the rotation is found without it too, so its weight is
  unmeasured). Identity wins ties within `uv_margin`, so an untextured or isotropic material is
  not rotated at random.
- **Albedo tint** (3 values) in closed form (`like_for_like_tints`): the render shown as the
  selection shows it (over the photo's background at the silhouette, softened) and read in the
  photo's regions, where it is affine in each part's tint; clamped to `tint_range`. The tint used
  to be fitted by Adam on the loss below, which reads each part inside its own rendered region:
  the photo's region there is mixed with the background near the silhouette (most of a thin
  part), and the tint brightened the parts to match; it relit worse (docs/decisions.md D66, D67).
- **Roughness scale** (log space) by Adam on Mitsuba's ``llvm_ad_rgb`` gradients
  (`render.gradients.GradientScene`), the tints held, clamped to `roughness_range`. The loss is
  per part, over the rendered part's eroded region: the relative L2 of the mean linear colour
  after the stage's exposure against the photo region's mean, plus `std_weight` x the same for the
  per-channel standard deviation (the light structural term: highlights and texture contrast,
  which roughness moves). Region statistics, not pixels, for the reason of docs/decisions.md D32:
  alignment is off by a few pixels. A new seed every step, low spp: Adam averages the noise.

All parts are refined in the same renders. `refine_parts` returns, per part, the refinement and the
gradient loss before (the library's material, UV placed) and after (both at seed 0, so the noise is
the same; the UV placement's own gain is in ``uv_cost``: identity's and the chosen point's).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from photoshape_flow.fit.appearance import Region, Weights, appearance, distance, erode, soften
from photoshape_flow.render.specs import Refinement

TEXTURED = ("albedo", "roughness", "normal")  # maps whose placement the UV transform moves


@dataclass(frozen=True)
class RefineSettings:
    """How hard to refine (the `FitConfig` refine fields)."""

    iterations: int = 8
    spp: int = 4
    learning_rate: float = 0.1
    tint_range: tuple[float, float] = (0.5, 2.0)
    roughness_range: tuple[float, float] = (0.5, 2.0)
    std_weight: float = 0.25
    roughness_prior: float = 0.0  # x sum of squared log roughness scales: stay at 1 without support
    uv: bool = True  # search the UV placement (`uv_search`)
    uv_scales: tuple[float, ...] = (0.5, 0.7, 1.0, 1.4, 2.0)
    uv_rotations: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0)  # degrees
    uv_margin: float = 0.03  # a UV hypothesis must beat identity by this fraction of its cost
    tint_overlap: float = 0.5  # a part's tint needs this share of its photo region covered by its render
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


def like_for_like_tints(scene: Any, rgba: np.ndarray, ids: np.ndarray, parts: Sequence[int], exposure: float,
                        bounds: tuple[float, float], min_overlap: float) -> dict[int, tuple[float, float, float]]:
    """Each part's albedo tint that makes the selection's comparison hold, solved in closed form.

    The render (`FitScene.render` at the scene's size, `ids` its part map) is shown as the selection
    shows it (`FitScene.exposed_linear`: at `exposure`, over the photo's background at the
    silhouette, softened like the photo) and read in the *photo's* regions, so near the silhouette
    both sides hold the same mixture with the background; a thin part's photo region is mostly that
    mixture, and a tint fitted to it otherwise brightens the part (docs/decisions.md D66). With one
    bounce that image is affine in each part's tint, so per channel the tints solve a small
    least-squares system (region i's mean = the photo's mean there), then are clamped to `bounds`.
    A part whose photo region holds less than `min_overlap` of its own rendered coverage is left
    out (tint 1): the region shows something else.
    """
    alpha = rgba[..., 3]
    coverage = {j: soften((alpha * (ids == j)).astype(np.float32), scene.blur) for j in parts}
    kept = [i for i in parts if i in scene.masks and float(coverage[i][scene.masks[i]].mean()) >= min_overlap]
    if not kept:
        return {}
    shown = {j: soften((rgba[..., :3] * (alpha * exposure * (ids == j))[..., None]).astype(np.float32), scene.blur)
             for j in kept}
    whole = scene.exposed_linear(rgba, exposure)
    tints = np.ones((len(kept), 3))
    for c in range(3):
        matrix = np.array([[float(shown[j][..., c][scene.masks[i]].mean()) for j in kept] for i in kept])
        target = np.array([float(scene.photo_linear[..., c][scene.masks[i]].mean()) for i in kept])
        rest = np.array([float(whole[..., c][scene.masks[i]].mean()) for i in kept]) - matrix.sum(axis=1)
        tints[:, c] = np.clip(np.linalg.lstsq(matrix, target - rest, rcond=None)[0], *bounds)
    return {i: (float(tints[k, 0]), float(tints[k, 1]), float(tints[k, 2])) for k, i in enumerate(kept)}


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

    `scene` is the pair's `fit.scene.FitScene` (its photo and regions) at `frame`'s size (see the
    module docstring for the search).
    """
    positions = {p.index: k for k, p in enumerate(scene.mesh.parts)}
    textured = [i for i in parts if i in positions and is_textured(materials[positions[i]])
                and i in scene.photo_stats]
    if not textured:
        return {}
    ids = frame.part_ids(scene.mesh, scene.camera)
    regions = {i: Region.of(erode(ids == i, settings.erode)) for i in textured}
    photo_lab = scene.photo_lab
    photo_orientation = {i: orientation(photo_lab, scene.masks[i]) for i in textured}
    weights = Weights(color=0.0, contrast=0.5, gradient=1.0, highlight=0.0)  # placement only: texture terms
    costs: dict[int, dict[tuple[float, float], float]] = {i: {} for i in textured}

    def measure(points: Mapping[int, tuple[float, float]]) -> None:
        """One render with part i at points[i]; each part's cost at its point."""
        trial = list(materials)
        for i, (scale, rotation) in points.items():
            trial[positions[i]] = with_refinement(materials[positions[i]], Refinement(uv_scale=scale,
                                                                                      uv_rotation=rotation))
        lab = scene.exposed_lab(scene.render(frame, trial, envmap), exposure)
        for i, point in points.items():
            rendered = appearance(lab, regions[i])
            if rendered is not None:
                costs[i][point] = distance(rendered, scene.photo_stats[i], weights) + settings.orientation_weight * (
                    float(np.linalg.norm(orientation(lab, regions[i].mask) - photo_orientation[i])))

    # coordinate search: every scale unrotated, then every rotation at each part's best scale
    for scale in settings.uv_scales:
        measure({i: (float(scale), 0.0) for i in textured})
    best_scale = {i: min(by_point, key=lambda k: by_point[k])[0] for i, by_point in costs.items() if by_point}
    for degrees in settings.uv_rotations:
        if degrees % 360:
            measure({i: (best_scale[i], math.radians(degrees)) for i in best_scale})
    out = {}
    for i, by_point in costs.items():
        if by_point:
            chosen = choose_uv(by_point, settings.uv_margin)
            out[i] = (chosen, {"identity": by_point.get((1.0, 0.0), math.nan), "chosen": by_point[chosen]})
    return out


class RegionLoss:
    """`region_loss` of every refined part on a Dr.Jit render, weighted by pixel share (differentiable).

    Each part's pixels are gathered into a block of equal length (padded with masked lanes that
    read 0), and one block sum per statistic gives every part's sums: a few kernels per step
    whatever the part count. Not a scatter-add into a per-part array: on the LLVM backend that
    many-to-few scatter crashed the process now and then (SIGSEGV in Dr.Jit's worker threads while
    the loss was evaluated; docs/decisions.md D44). `labels` (H, W): the part's position in `parts`
    for its region's pixels, -1 elsewhere.
    """

    def __init__(self, mi: Any, labels: np.ndarray, parts: Sequence[int],
                 targets: Mapping[int, tuple[np.ndarray, np.ndarray]], exposure: float, std_weight: float):
        import drjit as dr

        self.mi, self.dr = mi, dr
        self.parts = list(parts)
        flat = np.asarray(labels, np.int64).ravel()
        inside = flat >= 0
        self.pixels = mi.UInt32(np.flatnonzero(inside).astype(np.uint32))
        self.labels = mi.UInt32(flat[inside].astype(np.uint32))
        counts = np.bincount(flat[inside], minlength=len(self.parts)).astype(np.float64)
        members = [np.flatnonzero(flat == k) for k in range(len(self.parts))]
        self.block = max(1, max(len(x) for x in members))
        padded = np.zeros((len(self.parts), self.block), np.uint32)
        valid = np.zeros((len(self.parts), self.block), bool)
        for k, x in enumerate(members):
            padded[k, : len(x)], valid[k, : len(x)] = x, True
        self.block_pixels, self.block_valid = mi.UInt32(padded.ravel()), mi.Bool(valid.ravel())
        self.counts = mi.Float(np.maximum(counts, 1.0).astype(np.float32))
        self.shares = mi.Float((counts / max(counts.sum(), 1.0)).astype(np.float32))
        self.exposure = float(exposure)
        self.std_weight = float(std_weight)
        mean = np.array([targets[i][0] for i in self.parts], np.float64)
        std = np.array([targets[i][1] for i in self.parts], np.float64)
        level = mean + 0.02
        self.t_mean = [mi.Float(mean[:, c].astype(np.float32)) for c in range(3)]
        self.t_std = [mi.Float(std[:, c].astype(np.float32)) for c in range(3)]
        self.level = [mi.Float(level[:, c].astype(np.float32)) for c in range(3)]

    def __call__(self, image: Any) -> tuple[Any, Any]:
        """(total, per-part loss as a Float array in `parts` order) of an (H, W, 4) TensorXf render."""
        mi, dr = self.mi, self.dr
        size = len(self.parts)
        per_part = dr.zeros(mi.Float, size)
        for c in range(3):
            values = dr.gather(mi.Float, image.array, self.block_pixels * 4 + c, self.block_valid)
            sums, squares = dr.block_sum(values, self.block), dr.block_sum(values * values, self.block)
            mean = sums / self.counts
            std = dr.sqrt(dr.maximum(squares / self.counts - mean * mean, 1e-10))
            per_part += dr.square((self.exposure * mean - self.t_mean[c]) / self.level[c]) / 3.0
            per_part += self.std_weight * dr.square((self.exposure * std - self.t_std[c]) / self.level[c]) / 3.0
        return dr.sum(per_part * self.shares), per_part

    def values(self, per_part: Any) -> dict[int, float]:
        return {i: float(v) for i, v in zip(self.parts, np.array(per_part, np.float64).reshape(-1), strict=True)}


def refine_parts(frame: Any, scene: Any, materials: Sequence[Any], parts: Sequence[int], envmap: Any,
                 exposure: float, settings: RefineSettings = RefineSettings(),
                 uv_frame: Any = None) -> dict[int, PartRefinement]:
    """Refine the materials of `parts` (part indices; `materials[i]` is `scene.mesh.parts[i]`'s spec).

    `frame` renders the gradient loop (its own size: the statistics do not need the fit's), `uv_frame`
    the UV search and the tints' render, both read in the photo's regions, so at `scene`'s size
    (default `frame`, which must then be that size). Parts without a material (built-in), without a
    photo region or without rendered pixels are left out.
    """
    import drjit as dr

    mesh = scene.mesh
    positions = {p.index: k for k, p in enumerate(mesh.parts)}
    parts = [i for i in parts if i in positions and materials[positions[i]] is not None and i in scene.masks]
    if not parts:
        return {}
    targets = region_targets(scene.photo_linear, {i: scene.masks[i] for i in parts})
    uv = uv_search(uv_frame or frame, scene, materials, parts, envmap, exposure, settings) if settings.uv else {}
    placed = list(materials)
    for i, ((scale, rotation), _) in uv.items():
        placed[positions[i]] = with_refinement(materials[positions[i]], Refinement(uv_scale=scale,
                                                                                    uv_rotation=rotation))
    shown = uv_frame or frame  # the scene's size: the tints are read in the photo's regions
    tints = like_for_like_tints(scene, scene.render(shown, placed, envmap), shown.part_ids(mesh, scene.camera),
                                parts, exposure, settings.tint_range, settings.tint_overlap)
    ids = frame.render_ids(mesh, scene.camera)
    regions = {i: erode(ids == i, settings.erode) for i in parts}
    parts = [i for i in parts if regions[i].sum() >= 4 and i in targets]
    if not parts:
        return {}
    labels = np.full(ids.shape, -1, np.int64)
    for k, i in enumerate(parts):
        labels[regions[i]] = k
    with frame.gradient_scene(mesh, placed, scene.camera, envmap, settings.max_depth) as g:
        mi = g.mi
        loss = RegionLoss(mi, labels, parts, targets, exposure, settings.std_weight)
        opt = mi.ad.Adam(lr=settings.learning_rate)
        for i in parts:
            opt[f"rough_{i}"] = mi.Float(0.0)
        fixed = {positions[i]: mi.Color3f(*tints.get(i, (1.0, 1.0, 1.0))) for i in parts}

        def render(seed: int, tinted: bool = True) -> Any:
            rough = {positions[i]: dr.exp(opt[f"rough_{i}"]) for i in parts}
            return g.render(fixed if tinted else {}, rough, settings.spp, seed)

        with dr.suspend_grad():  # the loss before: the library's material, placed
            before = loss.values(loss(render(0, tinted=False))[1])
        for iteration in range(1, settings.iterations + 1):
            total, _ = loss(render(iteration))
            for i in parts:
                total += settings.roughness_prior * dr.square(opt[f"rough_{i}"])
            dr.backward(total)
            opt.step()
            for i in parts:
                opt[f"rough_{i}"] = dr.clip(opt[f"rough_{i}"], *log_range(settings.roughness_range))
        with dr.suspend_grad():
            after = loss.values(loss(render(0))[1])
        out = {}
        for i in parts:
            tint = tuple(round(t, 6) for t in tints.get(i, (1.0, 1.0, 1.0)))
            rough = round(float(math.exp(float(np.array(opt[f"rough_{i}"]).reshape(-1)[0]))), 6)
            (scale, rotation), uv_cost = uv.get(i, ((1.0, 0.0), {}))
            out[i] = PartRefinement(Refinement(tint, rough, scale, rotation),  # type: ignore[arg-type]
                                    before[i], after[i], uv_cost)
    return out
