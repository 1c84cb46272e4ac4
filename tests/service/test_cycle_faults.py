"""measure_frame on pairs a careless technician produces: lens cap on, lights off, cameras swapped (issue 15)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.cameras.base import StereoFrame
from cellctl.errors import FailureKind
from cellctl.service.codes import FAILURE_CODES
from cellctl.service.cycle import MeasureSettings, Refused, measure_frame
from cellctl.sim.scene import SoleScene
from cellctl.vision.calibration import Calibration
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.stereo_order import dominant_disparity
from firmware_io.registers import ErrorCode
from tests.sim_rig import half_size_rig


@pytest.mark.parametrize("level", [0, 255, 128], ids=["black", "white", "grey"])
def test_a_uniform_pair_is_a_scene_error_not_an_internal_one(level: int) -> None:
    calib = half_size_rig()
    width, height = calib.image_size
    image = np.full((height, width, 3), level, np.uint8)
    frame = StereoFrame(image, image.copy(), 0.0, 0.0)
    result = measure_frame(frame, SoleReconstructor(calib), MeasureSettings(2.0, 2.0))
    assert isinstance(result, Refused)
    assert result.failure is FailureKind.TOO_FEW_POINTS and "lighting" in result.reason
    assert FAILURE_CODES[result.failure] is ErrorCode.TOO_FEW_POINTS


@pytest.fixture(scope="module")
def rendered() -> tuple[Calibration, np.ndarray, np.ndarray]:
    calib = half_size_rig()
    pair = SoleScene.random(seed=3, calib=calib).render()
    return calib, pair.left, pair.right


def test_swapped_cameras_are_named_as_such(rendered: tuple[Calibration, np.ndarray, np.ndarray]) -> None:
    calib, left, right = rendered
    reconstructor = SoleReconstructor(calib)
    assert dominant_disparity(calib, left, right)[0] > reconstructor.min_disparity * 0.5
    result = measure_frame(StereoFrame(right, left, 0.0, 0.0), reconstructor, MeasureSettings(2.0, 2.0))
    assert isinstance(result, Refused)
    assert result.failure is FailureKind.CALIBRATION_MISMATCH and "swapped" in result.reason
