"""The simulated stereo rig: the "true" cameras behind every simulated image.

Two 1280x1024 cameras 60 mm apart looking down at the table from about 550 mm (RIG_HEIGHT_MM),
with a focal length chosen so that a 300 mm sole covers about 60 % of the image width (300 mm * 1400 px / 550 mm = 764 px), and the
small imperfections a real rig has: slightly different intrinsics, a tilt of under a degree between the
cameras and mild barrel distortion. Calibrating simulated checkerboard pairs must recover these values.
"""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.defaults import DEPTH_RANGE_MM

IMAGE_SIZE: tuple[int, int] = (1280, 1024)  # (width, height) px
# The rig's baseline mid-point above the table. Here rather than beside the renderer that poses the cameras
# (cellctl.sim.render.rig_pose): the rigs' heights derive from it, and importing the renderer for one number cost
# every user of the rigs (`cellctl simulate checkerboard`) about a second of start-up.
RIG_HEIGHT_MM: float = 550.0
BASELINE_MM: float = 60.0
WIDE_BASELINE_MM: float = 100.0  # the `wide` rig (SceneLook.rig): the same cameras further apart
NARROW_BASELINE_MM: float = 40.0  # the `narrow` rig: closer together
# Other cameras at the same place and field of view: the `coarse` rig's sensors have 0.75 times the pixels along each
# side (960 x 768, ~0.52 mm per pixel at the table), the `fine` rig's 1.25 times (1600 x 1280, ~0.31 mm): every
# threshold the measurement states in pixels is then met at another size in millimetres.
COARSE_SCALE: float = 0.75
FINE_SCALE: float = 1.25
# Mounted lower or higher, with a wider or a longer lens that sees the same table (focal lengths times the height
# against RIG_HEIGHT_MM): the same pixels on the table, but the rays at the sole's edges lean 1.3 times as far from
# the vertical on the `near` rig (up to ~25 degrees at a long sole's ends) and 0.7 times on the `far` one, and depth
# per disparity pixel is 0.76 and 1.36 times the default's.
NEAR_HEIGHT_MM: float = 420.0
FAR_HEIGHT_MM: float = 750.0


def default_rig(baseline_mm: float = BASELINE_MM, pixel_scale: float = 1.0, focal_scale: float = 1.0) -> Calibration:
    """The true calibration of the simulated rig (what a perfect calibration would find), its cameras
    `baseline_mm` apart, their sensors `pixel_scale` times the default's pixels along each side (the same field of
    view: focal lengths and principal points scale with the image), their lenses' focal lengths `focal_scale` times
    the default's (a narrower field of view above 1)."""
    K1 = np.array([[1402.0 * focal_scale, 0.0, 645.0], [0.0, 1399.0 * focal_scale, 508.0], [0.0, 0.0, 1.0]])
    K2 = np.array([[1396.0 * focal_scale, 0.0, 633.0], [0.0, 1395.0 * focal_scale, 517.0], [0.0, 0.0, 1.0]])
    # Pixel centres at (i + 0.5) / scale - 0.5: the principal point moves with the pixel grid, not just by the factor.
    to_scaled = np.array(
        [[pixel_scale, 0.0, 0.5 * (pixel_scale - 1.0)], [0.0, pixel_scale, 0.5 * (pixel_scale - 1.0)], [0.0, 0.0, 1.0]]
    )
    K1, K2 = to_scaled @ K1, to_scaled @ K2
    size = (round(IMAGE_SIZE[0] * pixel_scale), round(IMAGE_SIZE[1] * pixel_scale))
    # k1, k2, p1, p2, k3: mild barrel distortion of a typical 8 mm machine-vision lens.
    D1 = np.array([[-0.085, 0.060, 0.0004, -0.0003, 0.0]])
    D2 = np.array([[-0.080, 0.052, -0.0002, 0.0005, 0.0]])
    # The right camera is turned by under a degree about each axis w.r.t. the left one...
    R = cv2.Rodrigues(np.array([0.004, -0.012, 0.003]))[0]
    # ...and sits baseline_mm to its right; T is the left-to-right transform's translation (x_r = R x_l + T).
    right_centre_in_left = np.array([BASELINE_MM, -0.4, 0.6]) * baseline_mm / np.linalg.norm([BASELINE_MM, -0.4, 0.6])
    T = -R @ right_centre_in_left.reshape(3, 1)
    return Calibration.from_extrinsics(size, K1, D1, K2, D2, R, T)


def distorted_rig() -> Calibration:
    """A wide-angle rig (6 mm lenses): strong barrel distortion, unequal intrinsics, ~2 degrees between the cameras.

    Images of it are far from a pinhole's: a measurement that forgot to rectify, or rectified with a pinhole
    model, would be millimetres off at the image edges.
    """
    K1 = np.array([[1080.0, 0.0, 652.0], [0.0, 1076.0, 500.0], [0.0, 0.0, 1.0]])
    K2 = np.array([[1068.0, 0.0, 626.0], [0.0, 1071.0, 523.0], [0.0, 0.0, 1.0]])
    D1 = np.array([[-0.26, 0.11, 0.0012, -0.0009, -0.02]])
    D2 = np.array([[-0.24, 0.09, -0.0008, 0.0011, -0.015]])
    R = cv2.Rodrigues(np.array([0.012, -0.035, 0.01]))[0]
    right_centre_in_left = np.array([BASELINE_MM, -1.5, 2.0]) * BASELINE_MM / np.linalg.norm([BASELINE_MM, -1.5, 2.0])
    T = -R @ right_centre_in_left.reshape(3, 1)
    return Calibration.from_extrinsics(IMAGE_SIZE, K1, D1, K2, D2, R, T)


def rig_for(name: str) -> Calibration:
    """The simulated rig a SceneLook names (cellctl.sim.look.RIGS)."""
    rigs = {
        "default": default_rig,
        "distorted": distorted_rig,
        "wide": lambda: default_rig(WIDE_BASELINE_MM),
        "narrow": lambda: default_rig(NARROW_BASELINE_MM),
        "coarse": lambda: default_rig(pixel_scale=COARSE_SCALE),
        "fine": lambda: default_rig(pixel_scale=FINE_SCALE),
        "near": lambda: default_rig(focal_scale=NEAR_HEIGHT_MM / RIG_HEIGHT_MM),
        "far": lambda: default_rig(focal_scale=FAR_HEIGHT_MM / RIG_HEIGHT_MM),
    }
    if name not in rigs:
        raise ValueError(f"rig must be one of {', '.join(rigs)}, got {name!r}")
    return rigs[name]()


def rig_height_for(name: str) -> float:
    """How high above the table the rig a SceneLook names is mounted (its baseline's mid-point), mm."""
    return {"near": NEAR_HEIGHT_MM, "far": FAR_HEIGHT_MM}.get(name, RIG_HEIGHT_MM)


def depth_range_for(name: str) -> tuple[float, float]:
    """The depth range a line would configure for the rig a SceneLook names ([measure] depth_range_mm): the cell's
    default range moved with the rig's height, so that it holds the table and the tallest sole above it."""
    shift = rig_height_for(name) - RIG_HEIGHT_MM
    return DEPTH_RANGE_MM[0] + shift, DEPTH_RANGE_MM[1] + shift
