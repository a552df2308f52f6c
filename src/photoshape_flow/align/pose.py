"""Camera refinement by silhouette: the coarse pose moved until the shape's outline covers the photo's.

Coarse alignment picks one of a fixed set of viewpoints at a fixed distance: good enough to retrieve
the shape and to start the part map's flow, but a few degrees and a perspective off the photo's
camera. A diffuse part's render hardly notices; a specular one's does, because its reflections move
with the view, so fit's rendered comparison needs the photo's camera more closely than retrieval does
(docs/decisions.md D69). The silhouette carries that information without any material or light:
a greedy coordinate search over azimuth, elevation and distance (the field of view follows from
framing) maximises the intersection over union of the rendered silhouette with the photo's
foreground, at coarse-to-fine steps, within bounds around the coarse pose so a symmetric outline
cannot walk the camera away.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from photoshape_flow.align.fine import silhouette_iou
from photoshape_flow.render.camera import Camera

# (angle step in degrees, distance factor) per stage, coarse to fine
STEPS: tuple[tuple[float, float], ...] = ((4.0, 1.4), (2.0, 1.2), (1.0, 1.1))
MAX_ANGLE_DEG = 12.0  # the refined camera stays this close to the coarse one in azimuth and in elevation
DISTANCE_RANGE = (0.5, 2.0)  # and its distance within these factors of the coarse one
MIN_GAIN = 1e-4  # IoU gain a move must bring


@dataclass(frozen=True)
class RefinedPose:
    camera: Camera
    iou_before: float
    iou_after: float
    evaluations: int


def _moves(angle_deg: float, factor: float) -> list[tuple[str, float]]:
    step = math.radians(angle_deg)
    return [("azimuth", step), ("azimuth", -step), ("elevation", step), ("elevation", -step),
            ("distance", factor), ("distance", 1.0 / factor)]


def _within(camera: Camera, start: Camera) -> bool:
    turn = abs((camera.azimuth - start.azimuth + math.pi) % (2 * math.pi) - math.pi)
    ratio = camera.distance / start.distance
    return (turn <= math.radians(MAX_ANGLE_DEG) + 1e-9
            and abs(camera.elevation - start.elevation) <= math.radians(MAX_ANGLE_DEG) + 1e-9
            and DISTANCE_RANGE[0] - 1e-9 <= ratio <= DISTANCE_RANGE[1] + 1e-9
            and abs(camera.elevation) < math.pi / 2)


def refine_camera(silhouette: Callable[[Camera], np.ndarray], start: Camera, target: np.ndarray,
                  steps: Sequence[tuple[float, float]] = STEPS, max_moves: int = 40) -> RefinedPose:
    """The camera near `start` whose `silhouette` (a part map in the photo's frame, > 0 on the shape) best overlaps
    `target` (the photo's foreground in that frame): at each step size, take the first move of six
    (azimuth, elevation, distance, each way) that raises the IoU, until none does; `max_moves` bounds
    the moves in all."""
    target = np.asarray(target, bool)
    evaluations = 1
    best = before = silhouette_iou(silhouette(start), target)
    camera, moves = start, 0
    for angle, factor in steps:
        improved = True
        while improved and moves < max_moves:
            improved = False
            for name, change in _moves(angle, factor):
                value = getattr(camera, name)
                trial = camera.replace(**{name: value * change if name == "distance" else value + change})
                if not _within(trial, start):
                    continue
                evaluations += 1
                score = silhouette_iou(silhouette(trial), target)
                if score > best + MIN_GAIN:
                    best, camera, improved = score, trial, True
                    moves += 1
                    break
    return RefinedPose(camera, before, best, evaluations)
