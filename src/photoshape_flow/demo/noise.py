"""Periodic (tileable) noise on the torus for procedural SVBRDFs.

Everything here is periodic in both image axes by construction: spectral noise is white noise
filtered in the FFT domain (the inverse FFT of any spectrum is periodic), cellular noise measures
wrap-around distances, and analytic patterns use whole numbers of periods per tile. So textures
tile without seams, which the renderer's UV repetition needs.
"""

from __future__ import annotations

import numpy as np


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Texture coordinates (u right, v down the rows) in [0, 1) of an n x n tile."""
    t = np.arange(n, dtype=np.float64) / n
    v, u = np.meshgrid(t, t, indexing="ij")
    return u, v


def spectral(
    rng: np.random.Generator,
    n: int,
    *,
    beta: float = 2.0,
    fmin: float = 1.0,
    fmax: float | None = None,
    stretch: tuple[float, float] = (1.0, 1.0),
    angle: float = 0.0,
) -> np.ndarray:
    """Zero-mean, unit-std periodic noise with power spectrum ~ 1/f^beta between fmin and fmax cycles/tile.

    `stretch` = (su, sv) elongates features (su > 1 makes them longer along u, i.e. streaks along
    u, as in brushed metal or wood grain); `angle` rotates the anisotropy.
    """
    white = rng.standard_normal((n, n))
    fy = np.fft.fftfreq(n) * n
    fx = np.fft.rfftfreq(n) * n
    FY, FX = np.meshgrid(fy, fx, indexing="ij")
    c, s = np.cos(angle), np.sin(angle)
    fu = (c * FX + s * FY) * stretch[0]
    fv = (-s * FX + c * FY) * stretch[1]
    f = np.hypot(fu, fv)
    amp = np.where(f > 0, np.maximum(f, 1e-6) ** (-beta / 2), 0.0)
    amp[f < fmin] = 0.0
    if fmax is not None:
        amp *= np.exp(-((f / fmax) ** 4))
    out = np.fft.irfft2(np.fft.rfft2(white) * amp, s=(n, n))
    std = out.std()
    return (out - out.mean()) / (std if std > 0 else 1.0)


def cellular(rng: np.random.Generator, n: int, cells: int, jitter: float = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """Periodic Worley noise: distance to the nearest and second-nearest jittered point (in cell units)."""
    offs = rng.random((cells, cells, 2)) * jitter + (1 - jitter) / 2  # point position inside its cell
    coords = (np.arange(n) + 0.5) / n * cells
    cy, cx = np.meshgrid(coords, coords, indexing="ij")
    iy, ix = np.floor(cy).astype(int), np.floor(cx).astype(int)
    d1 = np.full((n, n), np.inf)
    d2 = np.full((n, n), np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            jy, jx = iy + dy, ix + dx
            o = offs[jy % cells, jx % cells]
            py, px = jy + o[..., 0], jx + o[..., 1]
            d = np.hypot(cy - py, cx - px)
            d2 = np.where(d < d1, d1, np.minimum(d2, d))
            d1 = np.minimum(d1, d)
    return d1, d2


def ridged(noise: np.ndarray, sharpness: float = 8.0) -> np.ndarray:
    """Thin ridges (1 on the zero crossings of `noise`, ~0 elsewhere): creases, scratches, cracks."""
    return np.exp(-sharpness * np.abs(noise))


def normalise01(x: np.ndarray) -> np.ndarray:
    lo, hi = float(x.min()), float(x.max())
    return (x - lo) / (hi - lo) if hi > lo else np.zeros_like(x)


def normal_from_height(height: np.ndarray, strength: float) -> np.ndarray:
    """OpenGL tangent-space normals (+x right, +y up the image) from a height map, with wrap-around.

    `strength` converts height units per pixel into slope; the result is unit length, float in [-1, 1].
    """
    dx = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) * 0.5
    drow = (np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) * 0.5
    dv = -drow  # rows go down, OpenGL +y goes up
    n = np.stack([-dx * strength, -dv * strength, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)
