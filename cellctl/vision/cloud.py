"""Measured points of one stereo pair: the matcher's disparities reprojected through Q.

Only really measured pixels become points: the left-right check passed, and the pixel has texture (a flat,
clipped patch matches at any disparity and can still pass the check).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from cellctl.images import grey_f32
from cellctl.stereo.kernels import measured_pixels
from cellctl.vision.calibration import Calibration

MIN_TEXTURE_DN = 0.5  # grey-level std over 5 x 5 px below which a pixel has nothing to match (sensor noise is ~1)


@dataclass
class StereoCloud:
    """Measured points of one pair in the rectified left camera frame (mm), with their pixels and colours."""

    points: np.ndarray  # N x 3 float64
    colors: np.ndarray  # N x 3 float32 BGR 0..255, from the (slightly smoothed) rectified left image
    pixels: np.ndarray  # N x 2 float64 (x, y) in the rectified left image
    disparity: np.ndarray  # N float64, px
    image_size: tuple[int, int]  # (width, height) of the rectified images
    timings: dict[str, float] = field(default_factory=dict)
    rectified: tuple[np.ndarray, np.ndarray] | None = None  # grey float32 pair, for sub-pixel refinement
    calibration: Calibration | None = None
    matched_pixels: int = 0  # pixels the matcher was given (a search region); 0: the whole image

    @property
    def matched_area(self) -> int:
        """Pixels the matcher looked at: what the measured fraction is a fraction of."""
        return self.matched_pixels or self.image_size[0] * self.image_size[1]


def disparity_range(calib: Calibration, depth_range_mm: tuple[float, float]) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering a working depth range, from d = f * B / Z."""
    near, far = float(depth_range_mm[0]), float(depth_range_mm[1])
    if not (0 < near < far):
        raise ValueError(f"depth range must be two distances MIN < MAX in mm, got {near:g} {far:g}")
    fb = calib.focal_px * calib.baseline_mm
    lowest = int(np.floor(fb / far))
    highest = int(np.ceil(fb / near))
    width = calib.image_size[0]
    if highest >= width:
        raise ValueError(
            f"depth range {near:g}-{far:g} mm needs disparities up to {highest} px, more than the image is wide "
            f"({width} px): raise the near limit"
        )
    return lowest, highest - lowest + 1


def cloud_from_disparity(
    calib: Calibration,
    fixed: np.ndarray,
    rect_left: np.ndarray,
    rect_right: np.ndarray,
    timings: dict[str, float],
    origin: tuple[int, int] = (0, 0),
    shift: int = 0,
) -> StereoCloud:
    """Every measured pixel of the matcher's final int16 map (x DISP_SCALE, INVALID where unmeasured) as a point.

    `fixed` may cover a crop of the rectified pair (cellctl.vision.search_region): its pixel (0, 0) is the
    full image's `origin` (x, y) and its disparities are the full pair's minus `shift`.
    """
    from cellctl.stereo import DISP_SCALE, INVALID

    grey_left, grey_right = grey_f32(rect_left), grey_f32(rect_right)
    x0, y0 = origin
    rows, cols = slice(y0, y0 + fixed.shape[0]), slice(x0, x0 + fixed.shape[1])
    # A flat patch (clipped highlight, covered lens) matches at any disparity and can still pass the
    # left-right check: such pixels are not measurements. The measured pixels in raster order, their flat index
    # (the maps are read with it as 1-D takes), pixels, disparities and the reprojection's x y d rows, in C
    # (cellctl.stereo.kernels.measured_pixels: two passes where numpy made ~15 over the map and the points).
    texture = _local_std(grey_left[rows, cols])
    flat, pixels, pixel_disparity, disparity = measured_pixels(
        fixed, texture, INVALID, MIN_TEXTURE_DN, origin, float(DISP_SCALE), shift
    )
    colours = np.take(_smoothed_colours(rect_left[rows, cols]).reshape(-1, 3), flat, axis=0)
    # Only the measured pixels through Q ([X Y Z W] = Q [x y d 1], cv2.reprojectImageTo3D's formula), as
    # a perspective transform of (x, y, d): no H x W x 3 map to build and gather from.
    # perspectiveTransform returns None for no points (an all-black or uniform pair: lens cap, lights off);
    # such a pair is a cloud of nothing, refused downstream as a scene error.
    points = cv2.perspectiveTransform(pixel_disparity.reshape(-1, 1, 3), calib.Q) if len(flat) else np.zeros((0, 3))
    return StereoCloud(
        points=points.reshape(-1, 3),
        colors=colours,
        pixels=pixels,
        disparity=disparity,
        image_size=calib.image_size,
        timings=timings,
        rectified=(grey_left, grey_right),
        calibration=calib,
        matched_pixels=0 if fixed.shape == grey_left.shape else fixed.size,
    )


def _local_std(grey: np.ndarray, size: int = 5) -> np.ndarray:
    mean = cv2.blur(grey, (size, size))
    return np.sqrt(np.maximum(cv2.blur(grey * grey, (size, size)) - mean * mean, 0.0))


def _smoothed_colours(image: np.ndarray) -> np.ndarray:
    """Per-pixel colour for the colour filter: a 3 x 3 mean tames sensor noise but keeps the edge position."""
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return cv2.boxFilter(image, cv2.CV_32F, (3, 3))  # float output straight from uint8: no rounding
