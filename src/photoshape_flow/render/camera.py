"""The one camera model of the project (alignment, training renders, export all use it).

Spherical parameterisation of section 4.1 of the paper, written with elevation instead of the polar
angle (phi = pi/2 - elevation):

- ``azimuth`` (radians) about +y; 0 puts the camera on the +z axis; it increases towards +x.
- ``elevation`` (radians) above the horizontal plane.
- ``distance`` from the origin in unit-cube units; ``fov`` the *horizontal* field of view in degrees.
- position = distance * (cos(el) sin(az), sin(el), cos(el) cos(az)); looks at the origin, +y up.
- Images are square; pixel (0, 0) is the top-left corner, x right, y down.

`to_world` is Mitsuba's ``look_at`` matrix (camera +z forward, +y up, +x *left*), so the matrix
given to the sensor and the one used by `project` are the same numbers. This module is pure numpy:
importing it never loads Mitsuba.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Camera:
    """A perspective camera on a sphere around the origin, looking at it with +y up."""

    azimuth: float
    elevation: float
    distance: float = 2.0
    fov: float = 50.0

    # -- geometry --------------------------------------------------------------------------
    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates, shape (3,)."""
        ce = math.cos(self.elevation)
        return self.distance * np.array(
            [ce * math.sin(self.azimuth), math.sin(self.elevation), ce * math.cos(self.azimuth)], np.float64
        )

    def to_world(self) -> np.ndarray:
        """4x4 camera-to-world matrix: columns are left, up, forward, position (Mitsuba's look_at)."""
        origin = self.position
        forward = -origin / np.linalg.norm(origin)
        up = np.array([0.0, 1.0, 0.0])
        left = np.cross(up, forward)
        norm = np.linalg.norm(left)
        if norm < 1e-9:  # looking straight up or down: any horizontal 'left' will do
            left = np.array([-math.cos(self.azimuth), 0.0, math.sin(self.azimuth)])
        else:
            left = left / norm
        true_up = np.cross(forward, left)
        matrix = np.eye(4)
        matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = left, true_up, forward, origin
        return matrix

    def focal(self, size: int) -> float:
        """Focal length in pixels for a square image of `size` pixels."""
        return 0.5 * size / math.tan(math.radians(self.fov) / 2.0)

    def project(self, points: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N, 3) into a square image of `size` pixels.

        Returns continuous pixel coordinates (N, 2) as (x, y), with (0, 0) the top-left *corner* of
        the image (so pixel (i, j) covers [i, i+1) x [j, j+1) and ``floor`` gives its index), and the
        depth (N,) along the viewing axis (negative behind the camera).
        """
        pts = np.atleast_2d(np.asarray(points, np.float64))
        world_to_cam = np.linalg.inv(self.to_world())
        local = pts @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        depth = local[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = self.focal(size)
            x = 0.5 * size - f * local[:, 0] / depth  # camera +x is image left
            y = 0.5 * size - f * local[:, 1] / depth  # camera +y is image up
        return np.stack([x, y], axis=1), depth

    def pixel_rays(self, size: int) -> np.ndarray:
        """Unit world-space directions (size, size, 3) through the pixel centres."""
        f = self.focal(size)
        centres = np.arange(size, dtype=np.float64) + 0.5
        lx = (0.5 * size - centres)[None, :] / f
        ly = (0.5 * size - centres)[:, None] / f
        local = np.stack(np.broadcast_arrays(lx, ly, np.ones((1, 1))), axis=-1)
        world = local @ self.to_world()[:3, :3].T
        return world / np.linalg.norm(world, axis=-1, keepdims=True)

    # -- serialisation ---------------------------------------------------------------------
    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Camera:
        return cls(
            azimuth=float(data["azimuth"]),
            elevation=float(data["elevation"]),
            distance=float(data.get("distance", 2.0)),
            fov=float(data.get("fov", 50.0)),
        )

    def replace(self, **changes: float) -> Camera:
        return replace(self, **changes)
