"""The depth range's hint (cellctl.vision.depth_hint): when it speaks and what it suggests."""

from __future__ import annotations

import numpy as np

from cellctl.sim.rig import default_rig
from cellctl.vision.depth_hint import SOLE_ROOM_MM, TABLE_ROOM_MM, depth_range_hint, fits, view_distance_mm


def test_a_table_with_room_for_the_sole_fits_and_gets_no_hint() -> None:
    assert fits(550.0, (450.0, 650.0)) and depth_range_hint(550.0, (450.0, 650.0)) == ""
    assert depth_range_hint(None, (450.0, 650.0)) == ""  # unknown distance: nothing to say


def test_the_range_must_leave_room_above_and_beyond_the_table() -> None:
    assert fits(450.0 + SOLE_ROOM_MM, (450.0, 650.0)) and not fits(450.0 + SOLE_ROOM_MM - 1.0, (450.0, 650.0))
    assert fits(650.0 - TABLE_ROOM_MM, (450.0, 650.0)) and not fits(650.0 - TABLE_ROOM_MM + 1.0, (450.0, 650.0))


def test_the_hint_suggests_a_range_round_the_table() -> None:
    hint = depth_range_hint(703.0, (450.0, 650.0))
    assert "about 703 mm" in hint and "450-650 mm" in hint and "about 600 800" in hint
    assert "about 150 350" in depth_range_hint(253.0, (450.0, 650.0))
    low, high = 150.0, 350.0
    assert fits(253.0, (low, high))  # what it suggests fits


def test_the_view_distance_comes_from_the_median_disparity() -> None:
    rig = default_rig()
    fb = rig.focal_px * rig.baseline_mm
    image = np.zeros((1024, 1280), np.uint8)

    def match(low: int, num: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        assert low == 0 and left.shape == (256, 320)
        out = np.full(left.shape, fb / 700.0 / 4.0, np.float32)  # quarter-scale disparity of a table at 700 mm
        out[:100] = np.nan
        return out

    assert abs(view_distance_mm(rig, image, image, match) - 700.0) < 1e-3

    def sparse(low: int, num: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        return np.full(left.shape, np.nan, np.float32)

    assert view_distance_mm(rig, image, image, sparse) is None
