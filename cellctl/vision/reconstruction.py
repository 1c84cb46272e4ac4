"""From a stereo pair to the sole's point cloud in the table frame (after Wang et al. 2022, section 2.2.4).

1. rectify with the calibration and match with `StereoMatcher` over the disparity range of the working
   depth range (d = f * B / Z); keep only pixels the matcher really measured (cellctl.vision.cloud);
2. segment: table plane, background removal, largest region, outliers (cellctl.vision.segmentation).

`SoleReconstructor.reconstruct(left, right)` runs all of it; `points_from_disparity` and `segment` are the
two halves, so a cloud from another source (e.g. the simulator's true depth) can be segmented the same way.

With a known table plane (taught, given, or learnt once with `learn_table`) the cycle matches only what can be the sole
(cellctl.vision.search_region): a coarse match finds what stands above the table, the full-resolution
match covers that region and the band of disparities from the table to its top. Whenever that shortcut
cannot be trusted (the table is not where it was, nothing found above it, the sole reaches the region's
edge, or the region's result is invalid) the whole pair is matched as without a plane, so the shortcut can
cost time but never change a refusal into a wrong value.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from cellctl.errors import FailureKind, MeasurementInputError
from cellctl.images import grey_f32
from cellctl.vision.calibration import Calibration
from cellctl.vision.cloud import StereoCloud, cloud_from_disparity, disparity_range
from cellctl.vision.defaults import DEPTH_RANGE_MM
from cellctl.vision.depth_hint import depth_range_hint, view_distance_mm
from cellctl.vision.image_noise import MAX_IMAGE_NOISE_DN, NOISY_EXPOSURES_DN, exposure_noise_dn, image_noise_dn
from cellctl.vision.search_region import SearchRegion, coarse_pair, coarse_range, find_region
from cellctl.vision.segmentation import (
    MIN_HEIGHT_MM,
    Reconstruction,
    ReconstructionRefused,
    ReconstructionResult,
    Segmentation,
)
from cellctl.vision.sole_region import pixel_boxes
from cellctl.vision.table import TablePlane
from cellctl.vision.teach import TaughtTable, TeachError, teach_table

__all__ = [
    "DEFAULT_DEPTH_RANGE_MM",
    "Reconstruction",
    "ReconstructionRefused",
    "ReconstructionResult",
    "SoleReconstructor",
    "StereoCloud",
    "TaughtTable",
    "disparity_range",
]

DEFAULT_DEPTH_RANGE_MM = DEPTH_RANGE_MM
# Only really measured pixels (no fill); the widest census window, because the sole's texture is weak:
# on simulated soles it halves the matcher's height noise for the same time.
# The binary census at its rho scale (the defaults before the ternary census): a ternary census fits windows
# of at most 32 pixels (64 bits), and the sole benchmark was validated with this one.
BINARY_CENSUS: dict[str, object] = {"census_threshold": 0, "lambda_census": 45.0}
SOLE_MATCHER_PARAMS: dict[str, object] = {"fill": "none", "census_window": (9, 7), **BINARY_CENSUS}
# The coarse match only has to say where something stands above the table: the default window and no
# medians (a third of its time; search_region's opening and largest region take out its isolated errors).
COARSE_MATCHER_PARAMS: dict[str, object] = {"fill": "none", "median": 0, "weighted_median": 0, **BINARY_CENSUS}
# The sub-pixel fits' patches, their disparity steps and their bicubic samples stay within this many pixels of the
# sole's measured pixels (left) and of where the right image sees them: a glue point's patch (up to 6 mm, ~15 px,
# 2 mm inside the outline) reaches ~10 px beyond them; the heights' 10 mm patches lie well inside the sole.
SURFACE_GREY_MARGIN_PX = 32
REGION_CUT_MM = 15.0  # a sole this close to a side of the search region may go on beyond it: match the whole pair


class SoleReconstructor:
    """Rectify, match, reproject and segment the sole; one instance per rig, reused across cycles."""

    def __init__(
        self,
        calib: Calibration,
        depth_range_mm: tuple[float, float] = DEFAULT_DEPTH_RANGE_MM,
        table_plane: TablePlane | None = None,
        min_height_mm: float = MIN_HEIGHT_MM,
        taught: TaughtTable | None = None,
        search_region: bool = True,
        **matcher_params: object,
    ) -> None:
        """search_region: with a known table plane, match only the region and band that can hold the sole
        (False: always the whole pair, e.g. to compare the two)."""
        if taught is not None and not taught.matches(calib):
            raise ValueError("the taught table was taught with another calibration: teach the empty table again")
        self.calib = calib
        self.taught = taught
        self.depth_range_mm = (float(depth_range_mm[0]), float(depth_range_mm[1]))
        self.min_disparity, self.num_disparities = disparity_range(calib, self.depth_range_mm)
        self.table_plane = table_plane if taught is None else taught.plane
        self.min_height_mm = float(min_height_mm)
        self.search_region = search_region
        self._matcher_params = {**SOLE_MATCHER_PARAMS, **matcher_params}
        if self._matcher_params["fill"] != "none":
            # Every valid pixel of the final map is taken as measured (points_from_disparity).
            raise ValueError(
                f"the sole reconstruction needs fill='none' (got {self._matcher_params['fill']!r}): "
                "filled disparities are guesses, not measurements"
            )
        self._matchers: dict[tuple[int, int, bool], object] = {}  # (min, num, coarse) -> StereoMatcher
        self.last_region: SearchRegion | None = None  # the region the last reconstruct matched (None: whole pair)
        self.last_fallback: str = ""  # why the last reconstruct matched the whole pair, when it had a plane
        self.last_from_mean = False  # the last reconstruct measured everything on the mean (a noisy exposure)

    def learn_table(self, left: np.ndarray, right: np.ndarray) -> TablePlane | None:
        """Without a taught table: find the table plane on one pair (RANSAC and image refinement; a sole may
        lie on the table) and keep it for the following cycles; None (nothing kept) when no table is found."""
        self.table_plane = None
        plane = self.reconstruct(left, right).table_plane
        self.table_plane = plane
        return plane

    def reconstruct(
        self,
        left: np.ndarray,
        right: np.ndarray,
        surface: tuple[np.ndarray, np.ndarray] | None = None,
        exposures: int | None = None,
    ) -> ReconstructionResult:
        """The sole's cloud from one raw (unrectified) stereo pair. `surface`: the mean of several exposures of the
        same view (cellctl.cameras.averaging), from which the sole's surface is fitted (`surface_grey`); default
        the pair itself. `exposures`: how many exposures that mean holds, where known (`surface_exposures`)."""
        self._check_pair(left, right)
        if surface is not None:
            self._check_pair(*surface)
        fitted = (left, right) if surface is None else surface
        timings: dict[str, float] = {}
        rect_left, rect_right = self._rectify(left, right, timings)
        self.last_region, self.last_fallback, self.last_from_mean = None, "", False
        noise = image_noise_dn(grey_f32(rect_left))
        removed = None  # what averaging removed from the last exposure (image_noise.exposure_noise_dn)
        if surface is not None:
            removed = exposure_noise_dn(left, surface[0])
            if noise > MAX_IMAGE_NOISE_DN or removed > NOISY_EXPOSURES_DN:
                # One exposure noisier than a clean camera's (or too noisy to measure at all: segmentation refuses
                # it): the mean has half the noise at four exposures, about what one exposure of a clean camera
                # has, so the matcher, the change test and the outline read the mean. Not on a clean exposure:
                # there every threshold was set on one exposure, and on the mean the change test's masks move
                # (docs/sole-benchmark.md, 26th round).
                rect_left, rect_right = self._rectify(*surface, timings)
                self.last_from_mean = True
        read = None if self.last_from_mean else noise  # the mean's noise is read by the segmentation
        if self.table_plane is not None and self.search_region:
            region, why = self._search_region(rect_left, rect_right, timings)
            if region is not None:
                result = self.segment(self._cloud(rect_left, rect_right, timings, region), read)
                cut_px = REGION_CUT_MM * self.calib.focal_px / self.table_plane.offset
                if isinstance(result, ReconstructionRefused):
                    why = f"refused: {result.reason}"
                elif region.cuts(result.sole_pixels, cut_px):
                    why = "the sole reaches the search region's edge"
                else:
                    self.last_region = region
                    return self._finished(result, *fitted, removed, exposures)
                spent = sum(v for k, v in result.timings.items() if k not in ("rectify", "coarse"))
                timings = {"rectify": timings["rectify"], "coarse": timings["coarse"], "region_attempt": spent}
            self.last_fallback = why
        result = self.segment(self._cloud(rect_left, rect_right, timings, None), read)
        if isinstance(result, ReconstructionRefused):
            hint = self._range_hint(rect_left, rect_right, result)
            if hint:
                result = replace(result, reason=f"{result.reason}; {hint}")
        return self._finished(result, *fitted, removed, exposures)

    def _finished(
        self,
        result: ReconstructionResult,
        left: np.ndarray,
        right: np.ndarray,
        removed: float | None,
        exposures: int | None,
    ) -> ReconstructionResult:
        """A found sole as `reconstruct` returns it: whether it was measured on the mean (`from_mean`), and its
        `surface_grey` pair: the sole's box (and SURFACE_GREY_MARGIN_PX round it) of each image rectified from the
        raw pair without rounding (`Calibration.rectify_grey`), in copies of the rectified grey pair. Only the sole's
        surface is fitted on the images; the whole pair would cost ~4-5 times as much. Where the raw pair is the mean of
        several exposures (`exposures` of them where known), `removed` is what averaging removed from the last one
        (`exposure_noise_dn`; None: the pair itself)."""
        if not isinstance(result, Reconstruction):
            return result
        result.from_mean = self.last_from_mean
        if result.rectified is None or len(result.sole_pixels) == 0:
            return result
        start = time.perf_counter()
        boxes = _sole_boxes(result, self.calib, result.rectified[0].shape)
        pair = []
        for side, raw, grey, box in zip(("left", "right"), (left, right), result.rectified, boxes, strict=True):
            fine = grey.copy()
            fine[box] = self.calib.rectify_grey(raw, side, box)
            pair.append(fine)
        result.timings["surface_grey"] = time.perf_counter() - start
        return replace(result, surface_grey=(pair[0], pair[1]), exposure_noise_dn=removed, surface_exposures=exposures)

    def points_from_disparity(self, left: np.ndarray, right: np.ndarray) -> StereoCloud:
        """Rectify, match the whole pair and reproject: every really measured pixel as a 3-D point."""
        self._check_pair(left, right)
        timings: dict[str, float] = {}
        rect_left, rect_right = self._rectify(left, right, timings)
        return self._cloud(rect_left, rect_right, timings, None)

    def _check_pair(self, left: np.ndarray, right: np.ndarray) -> None:
        for image in (left, right):
            try:
                self.calib.check_image(image)
            except ValueError as exc:
                raise MeasurementInputError(FailureKind.CALIBRATION_MISMATCH, str(exc)) from None

    def _rectify(self, left: np.ndarray, right: np.ndarray, timings: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        start = time.perf_counter()
        pair = self.calib.rectify(left, right)
        timings["rectify"] = time.perf_counter() - start
        return pair

    def _search_region(
        self, rect_left: np.ndarray, rect_right: np.ndarray, timings: dict[str, float]
    ) -> tuple[SearchRegion | None, str]:
        """The region and band worth matching, from a match at a quarter of the resolution."""
        from cellctl.stereo import to_float

        assert self.table_plane is not None
        start = time.perf_counter()
        low, num = coarse_range(self.min_disparity, self.num_disparities)
        small_left, small_right = coarse_pair(rect_left, rect_right)
        coarse = to_float(self._stereo_matcher(low, num, coarse=True).compute_fixed(small_left, small_right))
        region = find_region(self.calib, self.table_plane, coarse, (self.min_disparity, self.num_disparities))
        timings["coarse"] = time.perf_counter() - start
        return region

    def _cloud(
        self, rect_left: np.ndarray, rect_right: np.ndarray, timings: dict[str, float], region: SearchRegion | None
    ) -> StereoCloud:
        """Match the whole pair (region None) or a search region, and reproject the measured pixels."""
        start = time.perf_counter()
        # The final map alone (int16, x DISP_SCALE): without fill ("none") the medians keep unmeasured pixels
        # invalid, so a valid pixel of it is one that passed the left-right check. compute_detailed would
        # convert five maps to float for nothing.
        if region is None:
            fixed = self._stereo_matcher(self.min_disparity, self.num_disparities).compute_fixed(rect_left, rect_right)
            origin, shift = (0, 0), 0
        else:
            crop_left, crop_right = region.crop_pair(rect_left, rect_right)
            fixed = self._stereo_matcher(0, region.num_disparities).compute_fixed(crop_left, crop_right)
            origin, shift = (region.x0, region.y0), region.shift
        timings["match"] = time.perf_counter() - start
        start = time.perf_counter()
        cloud = cloud_from_disparity(self.calib, fixed, rect_left, rect_right, timings, origin, shift)
        timings["reproject"] = time.perf_counter() - start
        return cloud

    def segment(self, cloud: StereoCloud, image_noise: float | None = None) -> ReconstructionResult:
        """Table plane, background removal, largest region and outlier removal on a measured cloud
        (`image_noise`: its rectified left image's image_noise_dn, when already read)."""
        return Segmentation(cloud, self.table_plane, self.min_height_mm, self.taught, image_noise).run()

    def teach(self, left: np.ndarray, right: np.ndarray, exposure_noise: float | None = None) -> TaughtTable:
        """The taught table from a raw pair of the EMPTY fixture (cellctl.vision.teach); TeachError if not empty.
        exposure_noise: what averaging the pair's exposures removed (image_noise.exposure_noise_dn), if known."""
        cloud = self.points_from_disparity(left, right)
        try:
            taught = teach_table(cloud, self.calib, exposure_noise=exposure_noise)
        except TeachError as exc:
            hint = "" if cloud.rectified is None else self._range_hint(*cloud.rectified)
            if not hint:
                raise
            raise TeachError(f"{exc}; {hint}") from None
        # A table taught at the range's near end would leave no depth for the sole: say so now, not every cycle.
        hint = depth_range_hint(taught.plane.offset, self.depth_range_mm)
        if hint:
            raise TeachError(hint)
        return taught

    def _range_hint(
        self, rect_left: np.ndarray, rect_right: np.ndarray, refused: ReconstructionRefused | None = None
    ) -> str:
        """The remedy when the table does not fit the depth range (cellctl.vision.depth_hint), else "": its
        distance from the plane the refused run found, else from a wide match when too little was measured
        (the usual sign of a table outside the range)."""
        if refused is not None and refused.table_plane is not None:
            return depth_range_hint(refused.table_plane.offset, self.depth_range_mm)
        if refused is not None and refused.failure is not FailureKind.TOO_FEW_POINTS:
            return ""

        def match(low: int, num: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
            from cellctl.stereo import to_float

            return to_float(self._stereo_matcher(low, num, coarse=True).compute_fixed(left, right))

        return depth_range_hint(view_distance_mm(self.calib, rect_left, rect_right, match), self.depth_range_mm)

    def _stereo_matcher(self, low: int, num: int, coarse: bool = False):  # noqa: ANN202 - lazily imported core
        """One matcher per disparity range, kept: its buffers stay allocated between cycles of one size."""
        key = (low, num, coarse)
        if key not in self._matchers:
            from cellctl.stereo import StereoMatcher

            params = COARSE_MATCHER_PARAMS if coarse else self._matcher_params
            self._matchers[key] = StereoMatcher(low, num, **params)
        return self._matchers[key]


def _sole_boxes(
    sole: Reconstruction, calib: Calibration, shape: tuple[int, ...]
) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """(rows, columns) of the left and right rectified images round the sole's pixels, SURFACE_GREY_MARGIN_PX
    out; the right one shifted by the sole's disparities (d = f B / Z of its points in the camera frame)."""
    to_camera = np.linalg.inv(sole.camera_to_table)[2]
    depth = sole.sole_points @ to_camera[:3] + to_camera[3]
    disparity = calib.focal_px * calib.baseline_mm / np.maximum(depth, 1e-6)
    x, y = sole.sole_pixels[:, 0], sole.sole_pixels[:, 1]
    return pixel_boxes(x, y, disparity, SURFACE_GREY_MARGIN_PX, shape)
