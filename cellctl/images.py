"""Image conversions used across the package, written once (grey and BGR views of camera images)."""

from __future__ import annotations

import cv2
import numpy as np


def grey(image: np.ndarray) -> np.ndarray:
    """The image as one grey channel (BGR or BGRA converted; grey returned as it is)."""
    if image.ndim == 2:
        return image
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


def grey_f32(image: np.ndarray) -> np.ndarray:
    """`grey` as float32, for arithmetic on grey levels."""
    return grey(image).astype(np.float32)


def bgr(image: np.ndarray) -> np.ndarray:
    """The image as three BGR channels (grey replicated; BGR returned as it is)."""
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image
