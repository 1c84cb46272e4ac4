"""From a stereo pair to the sole's point cloud in the table frame (after Wang et al. 2022, section 2.2.4).

1. rectify with the calibration and match with `StereoMatcher` over the disparity range of the working
   depth range (d = f * B / Z); keep only pixels the matcher really measured (cellctl.vision.cloud);
2. segment: table plane, background removal, largest region, outliers (cellctl.vision.segmentation).

`SoleReconstructor.reconstruct(left, right)` runs all of it; `points_from_disparity` and `segment` are the
two halves, so a cloud from another source (e.g. the simulator's true depth) can be segmented the same way.
"""

from __future__ import annotations

import time

import numpy as np

from cellctl.errors import FailureKind, MeasurementInputError
from cellctl.vision.calibration import Calibration
from cellctl.vision.cloud import StereoCloud, cloud_from_disparity, disparity_range
from cellctl.vision.defaults import DEPTH_RANGE_MM
from cellctl.vision.segmentation import MIN_HEIGHT_MM, Reconstruction, Segmentation
from cellctl.vision.table import TablePlane

__all__ = ["DEFAULT_DEPTH_RANGE_MM", "Reconstruction", "SoleReconstructor", "StereoCloud", "disparity_range"]

DEFAULT_DEPTH_RANGE_MM = DEPTH_RANGE_MM
# Only really measured pixels (no fill); the widest census window, because the sole's texture is weak:
# on simulated soles it halves the matcher's height noise for the same time.
SOLE_MATCHER_PARAMS: dict[str, object] = {"fill": "none", "census_window": (9, 7)}


class SoleReconstructor:
    """Rectify, match, reproject and segment the sole; one instance per rig, reused across cycles."""

    def __init__(
        self,
        calib: Calibration,
        depth_range_mm: tuple[float, float] = DEFAULT_DEPTH_RANGE_MM,
        table_plane: TablePlane | None = None,
        min_height_mm: float = MIN_HEIGHT_MM,
        **matcher_params: object,
    ) -> None:
        self.calib = calib
        self.depth_range_mm = (float(depth_range_mm[0]), float(depth_range_mm[1]))
        self.min_disparity, self.num_disparities = disparity_range(calib, self.depth_range_mm)
        self.table_plane = table_plane
        self.min_height_mm = float(min_height_mm)
        self._matcher_params = {**SOLE_MATCHER_PARAMS, **matcher_params}
        if self._matcher_params["fill"] != "none":
            # Every valid pixel of the final map is taken as measured (points_from_disparity).
            raise ValueError(
                f"the sole reconstruction needs fill='none' (got {self._matcher_params['fill']!r}): "
                "filled disparities are guesses, not measurements"
            )
        self._matcher = None

    def reconstruct(self, left: np.ndarray, right: np.ndarray) -> Reconstruction:
        """The sole's cloud from one raw (unrectified) stereo pair."""
        return self.segment(self.points_from_disparity(left, right))

    def points_from_disparity(self, left: np.ndarray, right: np.ndarray) -> StereoCloud:
        """Rectify, match and reproject: every really measured pixel as a 3-D point."""
        for image in (left, right):
            try:
                self.calib.check_image(image)
            except ValueError as exc:
                raise MeasurementInputError(FailureKind.CALIBRATION_MISMATCH, str(exc)) from None
        timings: dict[str, float] = {}
        start = time.perf_counter()
        rect_left, rect_right = self.calib.rectify(left, right)
        timings["rectify"] = time.perf_counter() - start
        start = time.perf_counter()
        # The final map alone (int16, x DISP_SCALE): without fill ("none") the medians keep unmeasured pixels
        # invalid, so a valid pixel of it is one that passed the left-right check. compute_detailed would
        # convert five maps to float for nothing.
        fixed = self._stereo_matcher().compute_fixed(rect_left, rect_right)
        timings["match"] = time.perf_counter() - start
        start = time.perf_counter()
        cloud = cloud_from_disparity(self.calib, fixed, rect_left, rect_right, timings)
        timings["reproject"] = time.perf_counter() - start
        return cloud

    def segment(self, cloud: StereoCloud) -> Reconstruction:
        """Table plane, background removal, largest region and outlier removal on a measured cloud."""
        return Segmentation(cloud, self.table_plane, self.min_height_mm).run()

    def _stereo_matcher(self):  # noqa: ANN202 - StereoMatcher is imported lazily (compiled core)
        if self._matcher is None:
            from cellctl.stereo import StereoMatcher

            self._matcher = StereoMatcher(self.min_disparity, self.num_disparities, **self._matcher_params)
        return self._matcher
