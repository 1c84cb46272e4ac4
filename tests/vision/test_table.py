"""The table plane: the same cloud always gives the same plane."""

from __future__ import annotations

import numpy as np

from cellctl.sim.scene import SoleScene
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.table import find_table
from tests.sim_rig import half_size_rig


def test_the_same_cloud_gives_the_same_table_plane_every_call() -> None:
    # The half-size service cell's first pair: Open3D's segment_plane (seed set) returned one of three planes
    # from call to call on this cloud, 0.3 mm apart in height after the refits.
    calib = half_size_rig()
    pair = SoleScene.random(seed=2, color="white", calib=calib).render()
    points = SoleReconstructor(calib).points_from_disparity(pair.left, pair.right).points
    planes = [find_table(points) for _ in range(8)]
    assert all(p is not None for p in planes)
    first = planes[0]
    assert first is not None
    for plane in planes[1:]:
        assert plane is not None
        assert np.array_equal(plane.normal, first.normal) and plane.offset == first.offset
    # and it is the table: the simulated table lies ~550 mm below the left camera, facing it
    assert 500 < first.offset < 600 and first.normal[2] < -0.99


def test_no_plane_in_points_on_a_line() -> None:
    line = np.column_stack([np.linspace(0, 100, 500), np.zeros(500), np.full(500, 550.0)])
    assert find_table(line) is None
