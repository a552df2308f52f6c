"""The paper's viewpoint sweep: 456 distinct views on 10 rings, in the project's camera convention."""

from __future__ import annotations

import math

import numpy as np

from photoshape_flow.align.viewpoints import (
    NAMED_VIEWPOINT_SETS,
    PAPER_456,
    ViewpointParams,
    angular_errors_deg,
    cameras_from_rows,
    cameras_to_rows,
    ring_polar_angles,
    ring_sizes,
    viewpoint_array,
    viewpoints,
)


def test_paper_sweep_has_456_views_on_the_right_rings() -> None:
    assert ring_sizes(PAPER_456) == [35, 39, 42, 45, 47, 49, 50, 50, 50, 49]
    cams = viewpoints()
    assert len(cams) == 456
    phis = ring_polar_angles()
    assert len(phis) == 10
    assert math.isclose(phis[0], math.pi / 4) and math.isclose(phis[-1], 9 * math.pi / 16)
    rows = viewpoint_array()
    # elevation = pi/2 - phi: rings span [-pi/16, pi/4]
    assert math.isclose(rows[:, 1].max(), math.pi / 4) and math.isclose(rows[:, 1].min(), -math.pi / 16)
    assert np.all(rows[:, 2] == 2.0) and np.all(rows[:, 3] == 50.0)
    assert rows[:, 0].min() == 0.0 and rows[:, 0].max() < 2 * math.pi  # [0, 2pi): no duplicated 2pi view
    positions = np.round([c.position for c in cams], 9)
    assert len({tuple(p) for p in positions}) == 456


def test_azimuths_are_even_on_each_ring() -> None:
    rows = viewpoint_array()
    start = 0
    for n in ring_sizes():
        ring = rows[start : start + n]
        assert np.allclose(np.diff(ring[:, 0]), 2 * math.pi / n)
        assert np.allclose(ring[:, 1], ring[0, 1])
        start += n


def test_parameters_and_round_trip() -> None:
    params = ViewpointParams(num_rings=3, equator_azimuths=8, fov=40.0, distance=2.5)
    cams = viewpoints(params)
    assert len(cams) == sum(ring_sizes(params))
    assert all(c.fov == 40.0 and c.distance == 2.5 for c in cams)
    assert cameras_from_rows(cameras_to_rows(cams)) == cams
    assert ViewpointParams.from_dict(params.to_dict()) == params
    # the released code's ring sizes (327 views), here all distinct (its linspace repeated 0 = 2pi: 317)
    assert sum(ring_sizes(NAMED_VIEWPOINT_SETS["original-36"])) == 327


def test_angular_errors_wrap_azimuth() -> None:
    daz, delev = angular_errors_deg(np.radians(355.0), 0.1, np.radians(5.0), 0.0)
    assert math.isclose(float(daz), 10.0) and math.isclose(float(delev), math.degrees(0.1))
