"""From linear HDR radiance to display images, and the saturation statistic of training renders.

Tone mapping is deliberately plain (clip to 0..1, then the sRGB curve): it keeps a diffuse albedo
``a`` lit by unit radiance at exactly ``a`` in the 8-bit image, so the classifier sees albedos on
the scale the materials were authored in. Overexposed pixels are counted instead
(`saturated_fraction`); the original pipeline dropped training renders with >= 5% saturated.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from photoshape_flow.render.specs import linear_to_srgb


def to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB (clipped to 0..1) -> sRGB uint8."""
    return np.round(linear_to_srgb(linear) * 255.0).astype(np.uint8)


def composite(
    premultiplied: np.ndarray, alpha: np.ndarray, background: Literal["white", "transparent"]
) -> tuple[np.ndarray, np.ndarray]:
    """(hdr, srgb) from a premultiplied render and its coverage.

    ``white``: the HDR image is composited over radiance 1 (white in sRGB). ``transparent``: the HDR
    image stays premultiplied (background 0) and the sRGB image is un-premultiplied colour (black
    where nothing was hit), to be paired with the alpha channel.
    """
    rgb = np.maximum(np.asarray(premultiplied, np.float32), 0.0)
    a = np.clip(np.asarray(alpha, np.float32), 0.0, 1.0)[..., None]
    if background == "white":
        hdr = rgb + (1.0 - a)
        return hdr.astype(np.float32), to_srgb8(hdr)
    if background == "transparent":
        with np.errstate(divide="ignore", invalid="ignore"):
            straight = np.where(a > 1e-6, rgb / np.maximum(a, 1e-6), 0.0)
        return rgb.astype(np.float32), to_srgb8(straight)
    raise ValueError(f"background must be 'white' or 'transparent', got {background!r}")


def saturated_fraction(premultiplied: np.ndarray, alpha: np.ndarray, threshold: float = 1.0) -> float:
    """Fraction of covered pixels (alpha > 0.5) whose colour reaches `threshold` in any channel."""
    covered = np.asarray(alpha) > 0.5
    if not covered.any():
        return 0.0
    a = np.maximum(np.asarray(alpha, np.float32), 1e-6)[..., None]
    colour = np.asarray(premultiplied, np.float32) / a
    return float((colour[covered] >= threshold).any(axis=-1).mean())
