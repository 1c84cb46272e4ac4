"""The wall-height check (cellctl.vision.edge_checks.check_wall_height): a sole lower than LOW_WALL_MM all round
is refused as `wall_too_low`, because depth cannot show whether its wall leans out; one whose wall stands high
somewhere (a heel) passes, however low the rest of it."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.cameras.base import StereoFrame
from cellctl.errors import FailureKind
from cellctl.service.cycle import Measured, MeasureSettings, Refused, measure_frame
from cellctl.sim.look import SceneLook
from cellctl.sim.rig import default_rig
from cellctl.sim.scene import SoleScene, true_cloud
from cellctl.vision.edge_checks import LOW_WALL_MM, check_wall_height
from cellctl.vision.measurement import MeasurementRefused, measure_sole
from cellctl.vision.reconstruction import SoleReconstructor


def test_a_sole_low_all_round_is_refused_with_its_numbers() -> None:
    heights = np.full(700, 7.0)
    heights[::50] = np.nan  # edge points with no surface near them do not count
    problem = check_wall_height(heights)
    assert problem is not None and problem.kind is FailureKind.WALL_TOO_LOW
    assert "at most 7.0 mm high" in problem.reason
    assert f"needs {LOW_WALL_MM:.0f} mm" in problem.reason
    assert "2.5 mm (at 20 degrees) beyond the outline" in problem.reason  # 7 tan(20)


def test_a_high_heel_clears_a_low_forefoot() -> None:
    # A normal sole: 8 mm at the toe, 20 mm at the heel over the last third of the outline.
    heights = np.concatenate([np.full(450, 8.0), np.full(250, 20.0)])
    assert check_wall_height(heights) is None


def test_one_high_stretch_is_not_the_wall() -> None:
    # A flat sole with 5 % of its edge points reading high (a lump of depth) is still a flat sole.
    heights = np.concatenate([np.full(665, 7.0), np.full(35, 25.0)])
    assert check_wall_height(heights) is not None


def test_no_surface_near_the_edge_is_left_to_the_surface_checks() -> None:
    assert check_wall_height(np.full(100, np.nan)) is None


@pytest.mark.parametrize(("height", "refused"), [("flat", True), ("normal", False)])
def test_a_flat_sole_is_refused_on_its_true_depth_a_normal_one_is_measured(height: str, refused: bool) -> None:
    rig = default_rig()
    scene = SoleScene.random(2, "white", rig, SceneLook(height=height))
    pair = scene.render()
    result = measure_sole(SoleReconstructor(rig).segment(true_cloud(rig, pair.depth_left, pair.left)))
    if refused:
        assert isinstance(result, MeasurementRefused) and result.failure is FailureKind.WALL_TOO_LOW, result.reason
    else:
        assert result.valid, result.reason


def test_a_flat_sole_declared_vertical_is_measured_through_the_cycle() -> None:
    # The recipe's word (MeasureSettings.wall_draft_deg 0, from `[sole] wall = "vertical"`) reaches the check: the
    # same stereo pair is refused without it and measured within the acceptance tolerances with it.
    rig = default_rig()
    scene = SoleScene.random(2, "white", rig, SceneLook(height="flat"))
    pair = scene.render()
    frame, reconstructor = StereoFrame(pair.left, pair.right, 0.0, 0.0), SoleReconstructor(rig)
    refused = measure_frame(frame, reconstructor, MeasureSettings(2.0, 2.0))
    assert isinstance(refused, Refused) and refused.failure is FailureKind.WALL_TOO_LOW
    measured = measure_frame(frame, reconstructor, MeasureSettings(2.0, 2.0, wall_draft_deg=0.0))
    assert isinstance(measured, Measured), measured.reason
    assert scene.sole is not None
    assert abs(measured.measurement.length_mm - scene.sole.truth().length_mm) < 1.0
