"""Viewpoint sweeps for coarse alignment (section 4.1 of the paper).

The paper samples the polar angle phi in [pi/4, 9pi/16] on 10 rings and puts round(50 sin phi)
azimuths evenly over [0, 2pi) on each ring: 35+39+42+45+47+49+50+50+50+49 = 456 views. The released
code used 36 instead of 50 and a ``linspace`` that repeats the 2pi view (327 views, 317 distinct);
neither is copied. Polar angles become the project's elevations (elevation = pi/2 - phi).

A viewpoint set is described by `ViewpointParams`; its cameras are a pure function of them, so a set
stored in the database under (name, version) can always be checked against its parameters.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from photoshape_flow.render.camera import Camera


@dataclass(frozen=True)
class ViewpointParams:
    """Parameters of a ring sweep: `num_rings` polar angles, round(equator_azimuths sin phi) views each."""

    num_rings: int = 10
    phi_min: float = math.pi / 4
    phi_max: float = 9 * math.pi / 16
    equator_azimuths: int = 50
    fov: float = 50.0
    distance: float = 2.0

    def to_dict(self) -> dict[str, Any]:
        return {k: (int(v) if isinstance(v, int) else float(v)) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ViewpointParams:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})


PAPER_456 = ViewpointParams()
"""The paper's sweep: 456 views, fov 50 degrees, camera distance 2 (as in the original code)."""

NAMED_VIEWPOINT_SETS: dict[str, ViewpointParams] = {
    "paper-456": PAPER_456,
    # the released code's density (36 equatorial azimuths) without its duplicated 2pi view
    "original-36": ViewpointParams(equator_azimuths=36),
}


def ring_polar_angles(params: ViewpointParams = PAPER_456) -> np.ndarray:
    """The polar angles phi of the rings, evenly spaced over [phi_min, phi_max] inclusive."""
    if params.num_rings < 1:
        raise ValueError(f"num_rings must be >= 1, got {params.num_rings}")
    return np.linspace(params.phi_min, params.phi_max, params.num_rings)


def ring_sizes(params: ViewpointParams = PAPER_456) -> list[int]:
    """Azimuth count of each ring: round(equator_azimuths * sin(phi)), half away from zero, at least 1."""
    sizes = np.floor(params.equator_azimuths * np.sin(ring_polar_angles(params)) + 0.5).astype(int)
    return [max(1, int(n)) for n in sizes]


def viewpoint_array(params: ViewpointParams = PAPER_456) -> np.ndarray:
    """(N, 4) float64 rows [azimuth, elevation, distance, fov_deg], ring by ring, azimuth ascending.

    The row layout is the `ViewpointSet.cameras` JSON layout.
    """
    rows: list[tuple[float, float, float, float]] = []
    for phi, n in zip(ring_polar_angles(params), ring_sizes(params), strict=True):
        elevation = math.pi / 2 - float(phi)
        for j in range(n):
            rows.append((2 * math.pi * j / n, elevation, float(params.distance), float(params.fov)))
    return np.asarray(rows, np.float64)


def viewpoints(params: ViewpointParams = PAPER_456) -> list[Camera]:
    """The sweep as `Camera`s in the project convention."""
    return cameras_from_rows(viewpoint_array(params))


def cameras_from_rows(rows: Any) -> list[Camera]:
    """`Camera`s from [[azimuth, elevation, distance, fov], ...] (the stored JSON layout)."""
    return [Camera(float(a), float(e), float(d), float(f)) for a, e, d, f in np.asarray(rows, np.float64)]


def cameras_to_rows(cameras: list[Camera]) -> list[list[float]]:
    """The JSON layout of `ViewpointSet.cameras` for a list of cameras."""
    return [[float(c.azimuth), float(c.elevation), float(c.distance), float(c.fov)] for c in cameras]


def angular_errors_deg(
    azimuth_a: np.ndarray | float, elevation_a: np.ndarray | float,
    azimuth_b: np.ndarray | float, elevation_b: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray]:
    """Absolute azimuth (wrapped to [0, 180]) and elevation differences in degrees."""
    daz = np.abs((np.asarray(azimuth_a) - np.asarray(azimuth_b) + np.pi) % (2 * np.pi) - np.pi)
    delev = np.abs(np.asarray(elevation_a) - np.asarray(elevation_b))
    return np.degrees(daz), np.degrees(delev)
