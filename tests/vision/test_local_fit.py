"""Local plane fits along a glue path: a sloping surface round a pointed end keeps its height and slope."""

from __future__ import annotations

import numpy as np

from cellctl.vision.closed_path import smooth_along
from cellctl.vision.local_fit import local_planes


def test_a_rising_pointed_end_keeps_its_tip_height_and_slope() -> None:
    # A path round a 35 degree pointed end (tip at x = 0) on a surface rising 0.3 mm per mm towards the tip.
    s = np.linspace(-60.0, 60.0, 121)
    half = np.radians(17.5)
    xy = np.column_stack([-np.abs(s) * np.cos(half), s * np.sin(half)])
    z = 20.0 + 0.3 * xy[:, 0] + np.random.default_rng(0).normal(0.0, 0.05, len(s))
    height, gradient = local_planes(xy, xy, z, 6.0)
    tip = 60
    assert abs(height[tip] - 20.0) < 0.2  # the ridge shrinks the slope a little
    np.testing.assert_allclose(gradient[tip], [0.3, 0.0], atol=0.03)
    # Smoothing along the arc, as before, lowers the peak: what the plane fit is for.
    assert smooth_along(z, 6.0)[tip] < 19.0


def test_samples_on_one_line_give_the_lines_height_and_missing_samples_are_skipped() -> None:
    x = np.linspace(-20.0, 20.0, 41)
    xy = np.column_stack([x, np.zeros_like(x)])
    z = 5.0 + 0.1 * x
    z[20] = np.nan
    height, gradient = local_planes(np.array([[0.0, 0.0], [500.0, 0.0]]), xy, z, 4.0)
    assert abs(height[0] - 5.0) < 1e-6 and abs(gradient[0, 0] - 0.1) < 0.01 and gradient[0, 1] == 0.0
    assert np.isnan(height[1])
