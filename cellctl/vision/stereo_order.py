"""Are the left and right cameras swapped? The sign of the dominant disparity says.

After rectification a scene point lies further right in the left image than in the right one (d >= 0). The
table fills most of the view, so the dominant horizontal shift between the rectified images - found by
phase correlation on the whole image, ~30 ms at 640x512 - is the table's disparity. Swapped cameras (cables
exchanged, or left/right mixed up in the config) turn it negative, and the matcher, which searches positive
disparities only, then measures almost nothing: "too few points" with no hint. This module gives the hint.
"""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.images import grey_f32
from cellctl.vision.calibration import Calibration

#: Phase-correlation peak below which the shift is not trusted (a uniform or featureless pair gives ~0).
MIN_RESPONSE = 0.05


def dominant_disparity(calib: Calibration, left: np.ndarray, right: np.ndarray) -> tuple[float, float]:
    """(disparity px, peak response 0..1) of the pair's dominant horizontal shift after rectification."""
    rect_left, rect_right = calib.rectify(left, right)
    grey_left, grey_right = grey_f32(rect_left), grey_f32(rect_right)
    window = cv2.createHanningWindow((grey_left.shape[1], grey_left.shape[0]), cv2.CV_32F)
    (shift_x, _), response = cv2.phaseCorrelate(grey_left, grey_right, window)
    return -float(shift_x), float(response)  # phaseCorrelate gives the right image's shift: x_R - x_L = -d


def cameras_swapped(calib: Calibration, left: np.ndarray, right: np.ndarray, min_disparity: int) -> bool:
    """True when the pair's dominant disparity is clearly negative: left and right are exchanged."""
    disparity, response = dominant_disparity(calib, left, right)
    return response >= MIN_RESPONSE and disparity < -max(1.0, 0.5 * min_disparity)
