"""Where the view lies when the matcher measured too little of it: a rig mounted at another height than the
configured depth range assumes.

The matcher searches only the disparities of the depth range (cellctl.vision.cloud.disparity_range): a table
700 mm below cameras configured for 450-650 mm is simply not found, and the cycle (or `cellctl teach`) sees
"too few measured points", which sends a technician to the lights and the focus. On that path only (it costs
a match at a quarter of the resolution, ~0.1 s), the pair is matched again over every disparity a surface
NEAREST_MM or further away can have, and the view's median distance is compared with the range.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.search_region import COARSE_SCALE, coarse_pair

NEAREST_MM = 200.0  # no cell mounts its cameras closer to the table than this
# Share of the coarse pixels that must match over the wide search before the view's distance is believed.
MIN_MEASURED_SHARE = 0.3
# A depth range fits a table that leaves room above it for the tallest sole the cell measures (tall heels 50 mm)
# and a little beyond it for the table's far side under a tilted rig.
SOLE_ROOM_MM = 60.0
TABLE_ROOM_MM = 20.0
# A suggested range keeps the default's room round the table: 100 mm above it for the sole, 100 mm below.
SUGGESTED_ROOM_MM = 100.0
ROUND_TO_MM = 10.0

# (min_disparity, num_disparities) -> disparity map of the coarse pair (float px at the coarse scale, NaN where
# not measured); the reconstructor passes its cached coarse matcher.
CoarseMatch = Callable[[int, int, np.ndarray, np.ndarray], np.ndarray]


def view_distance_mm(
    calib: Calibration, rect_left: np.ndarray, rect_right: np.ndarray, match: CoarseMatch
) -> float | None:
    """Median distance (mm from the left camera) of what the rectified pair shows, or None if too little of it
    matches even over the wide search (dark, blurred or no texture: then the range is not the problem)."""
    highest = int(np.ceil(calib.focal_px * calib.baseline_mm / NEAREST_MM / COARSE_SCALE))
    small_left, small_right = (_as_uint8(image) for image in coarse_pair(rect_left, rect_right))
    num = min(highest, small_left.shape[1] // 2)
    disparity = match(0, num, small_left, small_right)
    measured = disparity[np.isfinite(disparity) & (disparity > 0)]
    if measured.size < MIN_MEASURED_SHARE * disparity.size:
        return None
    return float(calib.focal_px * calib.baseline_mm / (COARSE_SCALE * np.median(measured)))


def _as_uint8(image: np.ndarray) -> np.ndarray:
    """The matcher takes 8-bit images; a cloud keeps its rectified pair as float."""
    return image if image.dtype == np.uint8 else np.asarray(np.clip(np.round(image), 0, 255), np.uint8)


def fits(distance_mm: float, depth_range_mm: tuple[float, float]) -> bool:
    """Whether a table this far from the cameras leaves the depth range room for a sole above it."""
    near, far = depth_range_mm
    return near + SOLE_ROOM_MM <= distance_mm <= far - TABLE_ROOM_MM


def depth_range_hint(distance_mm: float | None, depth_range_mm: tuple[float, float]) -> str:
    """A sentence naming the remedy when a table this far away does not fit the depth range (`fits`; empty when it
    does or the distance is unknown)."""
    near, far = depth_range_mm
    if distance_mm is None or fits(distance_mm, depth_range_mm):
        return ""
    low = ROUND_TO_MM * round((distance_mm - SUGGESTED_ROOM_MM) / ROUND_TO_MM)
    high = ROUND_TO_MM * round((distance_mm + SUGGESTED_ROOM_MM) / ROUND_TO_MM)
    return (
        f"the table lies about {distance_mm:.0f} mm from the cameras, which the depth range {near:g}-{far:g} mm does "
        f"not cover with room for the sole above it ({SOLE_ROOM_MM:g} mm): set the depth range to about {low:g} "
        f"{high:g} (--depth-range, or [measure] depth_range_mm in the cell config) and teach again"
    )
