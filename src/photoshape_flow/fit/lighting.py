"""Lighting per exemplar: the envmap, rotation and exposure that best explain the photo (pure parts).

A hypothesis is one training envmap at one rotation about +y; the exposure is solved in closed form
for each (least squares in linear RGB between the rendered and the photo's per-part mean colours,
weighted by pixels: per-part means, not pixels, because the render and the photo are only aligned
up to a few pixels). The hypothesis with the lowest loss wins: the appearance loss of the ranking's
first materials, or (`shading_loss`) the layout of the shading alone, which no albedo can mimic.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from photoshape_flow.render.specs import linear_to_srgb, srgb_to_linear

EXPOSURE_RANGE = (1.0 / 32.0, 32.0)
SHADING_FLOOR = 1e-3  # linear radiance below which log-shading is clamped (black is not infinitely dark)
SHADING_SIGMA = 1.0 / 48.0  # of the frame's side: the blur that makes layouts comparable under misalignment
MIN_SHARED = 12  # pixels a part needs in both the render's and the photo's region to count


@dataclass(frozen=True)
class Hypothesis:
    """One lighting candidate: an envmap (row id) rotated about +y (radians)."""

    envmap_id: int
    rotation: float


def rotations(count: int) -> list[float]:
    """`count` rotations evenly spread over a turn, starting at 0."""
    return [2.0 * np.pi * i / max(1, count) for i in range(max(1, count))]


def region_means(linear: np.ndarray, masks: Mapping[int, np.ndarray]) -> dict[int, tuple[np.ndarray, int]]:
    """Mean linear RGB and pixel count of each non-empty region."""
    return {key: (linear[mask].reshape(-1, 3).mean(axis=0), int(mask.sum())) for key, mask in masks.items()
            if mask.any()}


def exposure(rendered: Mapping[int, tuple[np.ndarray, int]], photo: Mapping[int, tuple[np.ndarray, int]]) -> float:
    """The scale s minimising sum_p n_p |s r_p - f_p|^2 over the regions in both (1 when none), clamped."""
    num = den = 0.0
    for key, (r, n) in rendered.items():
        if key in photo:
            f, m = photo[key]
            w = float(min(n, m))
            num += w * float(np.dot(r, f))
            den += w * float(np.dot(r, r))
    if den <= 0.0:
        return 1.0
    return float(np.clip(num / den, *EXPOSURE_RANGE))


def exposed_srgb(linear: np.ndarray, scale: float) -> np.ndarray:
    """A linear render at an exposure, as sRGB float 0..1 (what the camera would have stored)."""
    return linear_to_srgb(np.asarray(linear, np.float64) * scale).astype(np.float32)


def photo_linear(srgb: np.ndarray) -> np.ndarray:
    """A photo (uint8 sRGB) in linear RGB, with the sRGB EOTF (not a 2.2 gamma)."""
    return srgb_to_linear(np.asarray(srgb, np.float64) / 255.0).astype(np.float32)


def best(losses: Sequence[tuple[Hypothesis, float, float]]) -> tuple[Hypothesis, float, float]:
    """The (hypothesis, exposure, loss) with the lowest finite loss; ties: the first."""
    finite = [item for item in losses if np.isfinite(item[2])]
    if not finite:
        raise ValueError("no lighting hypothesis could be scored (no part visible in both images)")
    return min(finite, key=lambda item: item[2])


def log_shading(linear: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """log linear RGB inside `mask`, blurred by `sigma` pixels without reaching outside it (a normalised
    convolution: a neighbouring part of another albedo, or the background, does not bleed in)."""
    rgb = np.asarray(linear, np.float32)[..., :3]
    if sigma > 0:
        weight = np.asarray(mask, np.float32)
        inside = cv2.GaussianBlur(rgb * weight[..., None], (0, 0), sigmaX=float(sigma))
        rgb = inside / np.maximum(cv2.GaussianBlur(weight, (0, 0), sigmaX=float(sigma)), 1e-6)[..., None]
    return np.log(np.maximum(rgb, SHADING_FLOOR))


def photo_shading(photo: np.ndarray, masks: Mapping[int, np.ndarray], sigma: float) -> dict[int, np.ndarray]:
    """The photo's `log_shading` inside each part's mask: computed once, compared with every hypothesis."""
    return {index: log_shading(photo, mask, sigma) for index, mask in masks.items()}


def shading_loss(rendered: np.ndarray, photo: Mapping[int, np.ndarray],
                 regions: Mapping[int, tuple[np.ndarray, np.ndarray]], sigma: float) -> float:
    """Pixel-weighted mean, over parts, of the variance of log(render / photo) inside the part, per channel.

    `rendered` is linear RGB, blurred inside each part's render mask (`log_shading`); `photo` the
    photo's `photo_shading`; `regions` part -> (render mask, photo mask), compared where both hold.
    Removing each part's mean log-ratio per channel removes its albedo (and the exposure and any white
    balance), so what is left is where the light and the shadows fall on the part, and the colour of
    the key light against the fill's: a hypothesis cannot win by tinting a wrong first material toward
    the photo's colour, which the appearance loss allows (D39, D49).
    """
    total = 0.0
    count = 0
    for index, (render_mask, photo_mask) in regions.items():
        both = np.asarray(render_mask, bool) & np.asarray(photo_mask, bool)
        n = int(both.sum())
        if n < MIN_SHARED:
            continue
        ratio = log_shading(rendered, render_mask, sigma)[both].astype(np.float64) - photo[index][both]
        total += float(((ratio - ratio.mean(axis=0)) ** 2).sum()) / ratio.shape[1]
        count += n
    return total / count if count else float("inf")


LOBE_RANGE = 3.0  # |log gain| of a lobe at most (a factor of 20 either way)


def lobe_shading(basis: Sequence[np.ndarray], photo: Mapping[int, np.ndarray],
                 regions: Mapping[int, tuple[np.ndarray, np.ndarray]],
                 sigma: float) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Part -> ((pixels, lobes, 3), (pixels, 3)): each lobe's render (linear RGB) blurred inside the part's
    render mask like `log_shading` (before the log), and the photo's `photo_shading`, at the pixels both
    masks of `regions` hold. The blur is linear, so the shading of any gains is the gain-weighted sum
    of the lobes'."""
    out = {}
    for index, (render_mask, photo_mask) in regions.items():
        both = np.asarray(render_mask, bool) & np.asarray(photo_mask, bool)
        if int(both.sum()) < MIN_SHARED:
            continue
        weight = np.asarray(render_mask, np.float32)
        norm = np.maximum(cv2.GaussianBlur(weight, (0, 0), sigmaX=float(sigma)), 1e-6)[..., None] if sigma > 0 else 1.0
        per_lobe = []
        for image in basis:
            rgb = np.asarray(image, np.float32)[..., :3]
            inside = cv2.GaussianBlur(rgb * weight[..., None], (0, 0), sigmaX=float(sigma)) / norm if sigma > 0 else rgb
            per_lobe.append(inside[both])
        out[index] = (np.stack(per_lobe, axis=1).astype(np.float64), np.asarray(photo[index])[both].astype(np.float64))
    return out


def _as_grid(log_gains: np.ndarray, lobes: int) -> np.ndarray:
    """(lobes, 1) grey or (lobes, 3) per-channel log gains from the optimiser's flat vector."""
    return np.asarray(log_gains, np.float64).reshape(lobes, -1)


def lobes_loss(log_gains: np.ndarray, shading: Mapping[int, tuple[np.ndarray, np.ndarray]], lobes: int,
               strength: float) -> tuple[float, np.ndarray]:
    """(loss, its gradient in the log gains) of `fit_lobes`: `shading_loss` of the lobes' weighted sum, plus
    `strength` times the variance of the log gains over the lobes (a lobe moves only as far as the
    photo asks). `log_gains`: `lobes` grey gains, or `lobes` x 3 per-channel ones (row-major)."""
    grid = _as_grid(log_gains, lobes)
    gains = np.broadcast_to(np.exp(grid), (lobes, 3))
    total, count = 0.0, 0
    grad = np.zeros((lobes, 3))
    for basis, photo in shading.values():
        mixed = np.einsum("pkc,kc->pc", basis, gains)
        ratio = np.log(np.maximum(mixed, SHADING_FLOOR)) - photo
        centred = ratio - ratio.mean(axis=0)
        total += float((centred ** 2).sum()) / 3.0
        # d/dg: the mean's own derivative drops out (the centred ratio sums to 0 over the pixels)
        live = (mixed > SHADING_FLOOR) / np.maximum(mixed, SHADING_FLOOR)
        grad += 2.0 / 3.0 * np.einsum("pc,pkc->kc", centred * live, basis)
        count += basis.shape[0]
    if not count:
        return 0.0, np.zeros(grid.size)
    grad = (grad * gains / count).sum(axis=1, keepdims=True) if grid.shape[1] == 1 else grad * gains / count
    centred_log = grid - grid.mean(axis=0)
    loss = total / count + strength * float((centred_log ** 2).mean())
    return loss, (grad + strength * 2.0 * centred_log / grid.size).ravel()


def fit_lobes(basis: Sequence[np.ndarray], photo: Mapping[int, np.ndarray],
              regions: Mapping[int, tuple[np.ndarray, np.ndarray]], sigma: float,
              strength: float, per_channel: bool = False) -> tuple[np.ndarray, float, float]:
    """(gains, shading loss before, after): the lobe gains whose lighting best explains where light and
    shadow fall on the photo's parts, each part's albedo removed (`shading_loss`).

    `basis`: the scene rendered under each lobe of the chosen envmap alone (linear RGB, one render per
    `specs.LOBE_AXES`), so a lighting with gains g renders as sum_k g_k basis_k; `photo`: `photo_shading`;
    `regions`: part -> (render mask, photo mask). The training envmaps' layouts are only a few; the
    lobes reshape the chosen one toward the photo's own light (a key light higher, a fill weaker)
    without asking the first materials, whose albedo the loss cannot see. `per_channel`: a gain per
    lobe and channel (a warm key against a cool fill; the light's overall colour stays the envmap's).
    The gains start at 1 (the envmap as it is), so the fit can only lower the loss; each channel's are
    scaled to a geometric mean of 1 (the exposure is solved afterwards). Returns (lobes,) grey or
    (lobes, 3) gains.
    """
    from scipy.optimize import minimize

    lobes = len(basis)
    shading = lobe_shading(basis, photo, regions, sigma)
    start = np.zeros(lobes * (3 if per_channel else 1))
    before = lobes_loss(start, shading, lobes, 0.0)[0]
    if not shading:
        return (np.ones((lobes, 3)) if per_channel else np.ones(lobes)), before, before
    result = minimize(lobes_loss, start, args=(shading, lobes, float(strength)), jac=True, method="L-BFGS-B",
                      bounds=[(-LOBE_RANGE, LOBE_RANGE)] * start.size, options={"maxiter": 80})
    grid = _as_grid(result.x, lobes)
    grid = grid - grid.mean(axis=0)
    after = lobes_loss(grid.ravel(), shading, lobes, 0.0)[0]
    gains = np.exp(grid)
    return (gains if per_channel else gains[:, 0]), before, after
