"""Where the sole can be: the part of the rectified pair and the band of disparities worth matching.

A cell knows its table plane (taught, or found once at set-up). In rectified images a plane
n . p + o = h (h mm above the table) has the disparity d = -B (n . (x - cx, y - cy, f)) / (o - h), affine
in the pixel for h = 0. So a cheap match of the pair at a quarter of the resolution over the full depth
range shows where something stands above the table; the full-resolution match then only covers that
region with a margin of table around it (the segmentation needs table around the sole: its colour
statistics, the border check) and only the disparities from the table under the region to the highest
thing the coarse match saw in it, with margins. On the simulated 1280x1024 cell that is about a quarter
of the pixels and a third of the disparities.

Nothing here decides what the sole is: a region that turns out too small (the sole reaches an edge of
the region that is not an image edge) is caught by `SearchRegion.cuts` and the caller matches the whole
pair instead; a pair where the coarse match finds nothing above the table, or a table that does not sit
where it was taught, also goes to the whole-pair match.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.footprint import largest_component
from cellctl.vision.table import TablePlane

COARSE_SCALE = 4  # the coarse match runs at 1/4 of the resolution: 1/16 of the pixels, 1/4 of the disparities
ABOVE_TABLE_MM = (
    5.0  # coarse pixels this far above the plane mark the object (at 4 mm, patterned tables' noise joins up)
)
REGION_MARGIN_MM = 25.0  # table kept around the object: the colour and change filters take it from 10-15 mm out
BAND_MARGIN_PX = 2  # disparities added below the table and above the highest coarse disparity
COARSE_ERROR_PX = COARSE_SCALE // 2  # half a coarse step: the coarse map is sub-pixel, its error well below
REGION_ALIGN_PX = 16  # region sides rounded out to this: few distinct sizes, so the matcher's buffers are reused
BAND_ALIGN = 4  # disparity counts rounded up to this, for the same reason
MAX_TABLE_SHIFT_PX = 1.5  # median coarse table disparity off the plane by more: the table is not where taught
MIN_OBJECT_PX = 50  # fewer coarse pixels above the table: nothing there (noise)
JOIN_PX = 9  # coarse pixels (~14 mm): pieces of one sole closer than this are joined


@dataclass(frozen=True)
class SearchRegion:
    """A crop of the rectified pair and the disparity band matched in it.

    The left crop is [y0:y1, x0:x1]; the right crop is the same rows and the columns shifted left by
    `shift` (the band's lowest disparity), so the crop pair is matched over [0, num_disparities) and a
    crop disparity d' is the full pair's d' + shift.
    """

    x0: int
    y0: int
    x1: int
    y1: int
    shift: int
    num_disparities: int
    image_size: tuple[int, int]  # (width, height) of the full rectified images

    @property
    def pixels(self) -> int:
        return (self.x1 - self.x0) * (self.y1 - self.y0)

    def crop_pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The left crop and the right crop shifted by `shift` (replicated border where it leaves the image)."""
        crop_left = np.ascontiguousarray(left[self.y0 : self.y1, self.x0 : self.x1])
        start = self.x0 - self.shift
        rows = right[self.y0 : self.y1]
        if start >= 0:
            return crop_left, np.ascontiguousarray(rows[:, start : self.x1 - self.shift])
        # As OpenCV-style matchers are padded: disparities are unchanged by a replicated left border.
        padded = cv2.copyMakeBorder(rows[:, : self.x1 - self.shift], 0, 0, -start, 0, cv2.BORDER_REPLICATE)
        return crop_left, padded

    def cuts(self, pixels: np.ndarray, margin_px: float) -> bool:
        """Whether points (N x 2 full-image x, y) come within `margin_px` of a side of the region that is not
        an image border: the object may go on beyond the region."""
        if len(pixels) == 0:
            return False
        width, height = self.image_size
        x, y = pixels[:, 0], pixels[:, 1]
        sides = (
            (self.x0 > 0 and bool(np.any(x < self.x0 + margin_px)))
            or (self.x1 < width and bool(np.any(x > self.x1 - 1 - margin_px)))
            or (self.y0 > 0 and bool(np.any(y < self.y0 + margin_px)))
            or (self.y1 < height and bool(np.any(y > self.y1 - 1 - margin_px)))
        )
        return sides


def plane_disparity(calib: Calibration, plane: TablePlane, x: np.ndarray, y: np.ndarray, height_mm: float = 0.0):  # noqa: ANN201
    """Disparity (px, rectified pair) of the plane `height_mm` above the table at pixels (x, y)."""
    f, cx, cy, baseline = calib.focal_px, calib.P1[0, 2], calib.P1[1, 2], calib.baseline_mm
    n = plane.normal
    return -baseline * (n[0] * (x - cx) + n[1] * (y - cy) + n[2] * f) / (plane.offset - height_mm)


def coarse_pair(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rectified pair at 1/COARSE_SCALE of the resolution (area average: no aliasing)."""
    height, width = left.shape[:2]
    size = (width // COARSE_SCALE, height // COARSE_SCALE)
    return (cv2.resize(left, size, interpolation=cv2.INTER_AREA), cv2.resize(right, size, interpolation=cv2.INTER_AREA))


def coarse_range(min_disparity: int, num_disparities: int) -> tuple[int, int]:
    """(min, num) at the coarse scale covering the full-resolution range, one step wider at each end."""
    low = max(min_disparity // COARSE_SCALE - 1, 0)
    high = -(-(min_disparity + num_disparities - 1) // COARSE_SCALE) + 1
    return low, high - low + 1


def find_region(
    calib: Calibration, plane: TablePlane, coarse: np.ndarray, full_range: tuple[int, int]
) -> tuple[SearchRegion | None, str]:
    """The region and band to match at full resolution from a coarse disparity map (float px at the coarse
    scale, NaN where unmeasured), or None and why the whole pair must be matched."""
    width, height = calib.image_size
    ys, xs = np.nonzero(np.isfinite(coarse))
    if len(xs) < 0.1 * coarse.size:
        return None, "the coarse match measured too little of the view"
    # Coarse pixel centres in full-resolution coordinates.
    fx, fy = (xs + 0.5) * COARSE_SCALE - 0.5, (ys + 0.5) * COARSE_SCALE - 0.5
    disparity = coarse[ys, xs] * COARSE_SCALE
    residual = disparity - plane_disparity(calib, plane, fx, fy)
    shift = float(np.median(residual))
    if abs(shift) > MAX_TABLE_SHIFT_PX:
        return None, f"the table is {shift:+.1f} px of disparity off the taught plane"
    above = _largest_object(coarse.shape, xs, ys, disparity > plane_disparity(calib, plane, fx, fy, ABOVE_TABLE_MM))
    if np.count_nonzero(above) < MIN_OBJECT_PX:
        return None, "nothing above the table in the coarse match"
    mm_per_px = plane.offset / calib.focal_px  # pixel footprint on the table, near enough for a margin
    margin = REGION_MARGIN_MM / mm_per_px + COARSE_SCALE
    x0 = _align_down(fx[above].min() - margin)
    y0 = _align_down(fy[above].min() - margin)
    x1 = min(_align_up(fx[above].max() + margin + 1), width)
    y1 = min(_align_up(fy[above].max() + margin + 1), height)
    x0, y0 = max(x0, 0), max(y0, 0)
    inside = (fx >= x0) & (fx < x1) & (fy >= y0) & (fy < y1)
    corners_x, corners_y = np.array([x0, x1 - 1, x0, x1 - 1]), np.array([y0, y0, y1 - 1, y1 - 1])
    low = int(np.floor(plane_disparity(calib, plane, corners_x, corners_y).min())) - BAND_MARGIN_PX
    high = int(np.ceil(disparity[inside].max())) + COARSE_ERROR_PX + BAND_MARGIN_PX
    full_low, full_num = full_range
    low, high = max(low, full_low), min(high, full_low + full_num - 1)
    if high <= low:
        return None, "the band of disparities is empty"
    num = -(-(high - low + 1) // BAND_ALIGN) * BAND_ALIGN
    return SearchRegion(x0, y0, x1, y1, low, num, (width, height)), ""


def _largest_object(shape: tuple[int, ...], xs: np.ndarray, ys: np.ndarray, above: np.ndarray) -> np.ndarray:
    """Which of the coarse pixels (xs, ys) flagged `above` belong to the largest object: the sole is the
    largest region (cellctl.vision.segmentation), and scattered coarse mismatches must not widen the region.

    A low or weakly textured part of a sole (a thin forefoot, a cusped tip) can come out of the coarse match
    in pieces: pieces closer than JOIN_PX are joined (closing). A sole barely taller than ABOVE_TABLE_MM may
    still be found in part: its points then reach the region's side and the whole pair is matched.
    """
    mask = np.zeros(shape, np.uint8)
    mask[ys[above], xs[above]] = 1
    opened = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))  # single-pixel mismatches
    joined = cv2.morphologyEx(opened, cv2.MORPH_CLOSE, np.ones((JOIN_PX, JOIN_PX), np.uint8))
    labels, largest = largest_component(joined)
    if largest == 0:
        return np.zeros(len(xs), bool)
    return (labels[ys, xs] == largest) & above


def _align_down(value: float) -> int:
    return int(np.floor(value / REGION_ALIGN_PX)) * REGION_ALIGN_PX


def _align_up(value: float) -> int:
    return int(np.ceil(value / REGION_ALIGN_PX)) * REGION_ALIGN_PX
