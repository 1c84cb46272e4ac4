"""Named disparity methods compared by the Middlebury evaluation (the rows of the paper's Table 3).

Every method is a callable `(left, right, min_disparity, num_disparities) -> disparity` taking
8-bit BGR images and returning a float32 map of the left image with NaN where it gives no
disparity.  Our own methods come from `cellctl.stereo.matcher.StereoMatcher` (the compiled C core),
imported only when they run so the OpenCV references work without it.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from cellctl.eval.middlebury import DisparityMethod

# OpenCV's block matchers work in 1/16 px and need a multiple of 16 disparities.
_CV_DISP_SCALE = 16

# The SAD reference (paper's [16]: local block matching, no aggregation).  OpenCV StereoBM sums
# absolute differences of x-Sobel prefiltered grey images over the block and takes the
# winner; its texture and uniqueness checks leave ambiguous pixels invalid, as the paper
# describes for [16] ("many missing and empty areas").  No speckle filter, no left-right check.
SAD_BLOCK_SIZE = 9  # of 5, 7, 9, 11, 15 the lowest average (9 and 11 tie), one size for all scenes
SAD_TEXTURE_THRESHOLD = 10  # OpenCV default
SAD_UNIQUENESS_RATIO = 15  # OpenCV default

# OpenCV StereoSGBM with its usual settings (OpenCV's stereo_match sample, speckle range in px).
SGBM_BLOCK_SIZE = 3  # the sample's window; of 3, 5, 7 the lowest 12-number average in both modes
SGBM_UNIQUENESS_RATIO = 10
SGBM_SPECKLE_WINDOW = 100
SGBM_SPECKLE_RANGE = 2  # px; OpenCV multiplies it by 16 internally
SGBM_DISP12_MAX_DIFF = 1
SGBM_PREFILTER_CAP = 63


@dataclass(frozen=True)
class Method:
    """A disparity method as listed by `cellctl eval middlebury --methods`."""

    name: str
    summary: str
    compute: DisparityMethod
    paper_column: str | None = None  # the paper's Table 3 column it corresponds to
    requires: str | None = None  # module that must import for it to run


# Matcher objects are made once per disparity range and reused, as a running cell uses them:
# the timings then compare computing, not allocating buffers, for every method alike.
_cached = functools.lru_cache(maxsize=16)


@_cached
def _stereo_bm(min_d: int, num_d: int) -> Any:
    bm = cv2.StereoBM.create(numDisparities=num_d, blockSize=SAD_BLOCK_SIZE)
    bm.setMinDisparity(min_d)
    bm.setTextureThreshold(SAD_TEXTURE_THRESHOLD)
    bm.setUniquenessRatio(SAD_UNIQUENESS_RATIO)
    bm.setSpeckleWindowSize(0)
    bm.setDisp12MaxDiff(-1)
    return bm


def sad_block_matching(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int) -> np.ndarray:
    """SAD block matching (OpenCV StereoBM on grey images), NaN where it finds no disparity."""
    return _opencv_disparity(_stereo_bm, _grey(left), _grey(right), min_disparity, num_disparities)


def sgbm_create(mode: int, min_disparity: int, num_disparities: int, channels: int) -> Any:
    """OpenCV StereoSGBM with the settings every comparison here uses (docs/benchmarks.md, section 1)."""
    area = channels * SGBM_BLOCK_SIZE**2
    return cv2.StereoSGBM.create(
        minDisparity=min_disparity,
        numDisparities=num_disparities,
        blockSize=SGBM_BLOCK_SIZE,
        P1=8 * area,
        P2=32 * area,
        disp12MaxDiff=SGBM_DISP12_MAX_DIFF,
        preFilterCap=SGBM_PREFILTER_CAP,
        uniquenessRatio=SGBM_UNIQUENESS_RATIO,
        speckleWindowSize=SGBM_SPECKLE_WINDOW,
        speckleRange=SGBM_SPECKLE_RANGE,
        mode=mode,
    )


def opencv_sgbm(mode: int) -> DisparityMethod:
    """OpenCV StereoSGBM in the given mode (MODE_HH4, MODE_SGBM_3WAY, ...) with its post-processing."""

    @_cached
    def create(min_d: int, num_d: int, channels: int) -> Any:
        return sgbm_create(mode, min_d, num_d, channels)

    def compute(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int) -> np.ndarray:
        channels = 1 if left.ndim == 2 else left.shape[2]
        return _opencv_disparity(lambda lo, n: create(lo, n, channels), left, right, min_disparity, num_disparities)

    return compute


def background_fill(disparity: np.ndarray) -> np.ndarray:
    """Each invalid (NaN) pixel gets the smaller of the nearest valid disparities left and right in its row.

    The simple fill of the comparison: invalid pixels are mostly occlusions, which belong to the
    farther surface.  A row without any valid pixel stays invalid.
    """
    d = np.asarray(disparity, np.float32)
    valid = np.isfinite(d)
    width = d.shape[1]
    columns = np.arange(width)
    left_at = np.maximum.accumulate(np.where(valid, columns, -1), axis=1)
    right_at = np.minimum.accumulate(np.where(valid, columns, width)[:, ::-1], axis=1)[:, ::-1]
    left = np.take_along_axis(d, np.clip(left_at, 0, width - 1), axis=1)
    right = np.take_along_axis(d, np.clip(right_at, 0, width - 1), axis=1)
    left[left_at < 0] = np.nan
    right[right_at >= width] = np.nan
    with np.errstate(invalid="ignore"):
        return np.where(valid, d, np.fmin(left, right)).astype(np.float32)


def filled(method: DisparityMethod) -> DisparityMethod:
    """The method followed by `background_fill` (the fill is part of its timed call)."""

    def compute(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int) -> np.ndarray:
        return background_fill(method(left, right, min_disparity, num_disparities))

    return compute


def stereo_matcher(**options: Any) -> DisparityMethod:
    """Our matcher (`cellctl.stereo.matcher.StereoMatcher`, which converts BGR to grey) with the given options."""

    @_cached
    def create(matcher_class: type, min_d: int, num_d: int) -> Any:
        return matcher_class(min_d, num_d, **options)

    def compute(left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int) -> np.ndarray:
        from cellctl.stereo.matcher import StereoMatcher  # the C core is only needed when this runs

        # the class is part of the key, so a replaced class (as in tests) never gets a stale object
        return create(StereoMatcher, min_disparity, num_disparities).compute(left, right)

    return compute


def _grey(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def _opencv_disparity(
    create: Any, left: np.ndarray, right: np.ndarray, min_disparity: int, num_disparities: int
) -> np.ndarray:
    """Run an OpenCV block matcher on exactly [min, min + num - 1] and return float px, NaN = invalid.

    OpenCV needs a multiple of 16 disparities and leaves the first min + num columns
    without a disparity.  Rounding the count up would widen that strip and allow
    disparities outside the range, so both images get the extra columns as replicated
    border on the left (disparities are unchanged by padding both), the padding is cut
    off again, and disparities won at a level outside the range become invalid.
    """
    if num_disparities < 1:
        raise ValueError(f"num_disparities must be >= 1, got {num_disparities}")
    rounded = -(-num_disparities // _CV_DISP_SCALE) * _CV_DISP_SCALE
    extra = rounded - num_disparities
    if extra:
        left = cv2.copyMakeBorder(left, 0, 0, extra, 0, cv2.BORDER_REPLICATE)
        right = cv2.copyMakeBorder(right, 0, 0, extra, 0, cv2.BORDER_REPLICATE)
    raw = create(min_disparity, rounded).compute(left, right)[:, extra:]
    disparity = raw.astype(np.float32) / _CV_DISP_SCALE
    max_disparity = min_disparity + num_disparities - 1
    # OpenCV marks invalid pixels with (min - 1) * 16.  Its sub-pixel step moves a winner by at
    # most half a pixel, so anything above max + 0.5 won at a level outside the range.
    invalid = (raw <= (min_disparity - 1) * _CV_DISP_SCALE) | (disparity > max_disparity + 0.5)
    disparity[invalid] = np.nan
    return disparity


METHODS: dict[str, Method] = {
    method.name: method
    for method in (
        Method(
            "sad-bm",
            "SAD block matching, local, no aggregation (OpenCV StereoBM)",
            sad_block_matching,
            paper_column="Reference [16] SAD",
        ),
        Method(
            "census-8path",
            "Census cost + 8-path semi-global aggregation (StereoMatcher)",
            # the paper's binary census, at the rho scale it had before the ternary default
            stereo_matcher(cost="census", paths=8, census_threshold=0, lambda_census=45.0),
            paper_column="Census + 8-path",
            requires="cellctl.stereo.matcher",
        ),
        Method(
            "proposed",
            "Census+BT cost, 4-path aggregation, LR check, fill, median (StereoMatcher defaults)",
            stereo_matcher(),
            paper_column="Proposed",
            requires="cellctl.stereo.matcher",
        ),
        Method(
            "opencv-hh4", "OpenCV StereoSGBM MODE_HH4 with its post-processing", opencv_sgbm(cv2.StereoSGBM_MODE_HH4)
        ),
        Method(
            "opencv-hh4-fill",
            "OpenCV StereoSGBM MODE_HH4 with its post-processing and a background fill of invalid pixels",
            filled(opencv_sgbm(cv2.StereoSGBM_MODE_HH4)),
        ),
        Method(
            "opencv-3way",
            "OpenCV StereoSGBM MODE_SGBM_3WAY with its post-processing",
            opencv_sgbm(cv2.StereoSGBM_MODE_SGBM_3WAY),
        ),
    )
}


def select_methods(names: Iterable[str] | None = None) -> list[Method]:
    """The named methods (all by default), checked to exist and to be runnable here."""
    chosen = list(names) if names is not None else list(METHODS)
    unknown = [name for name in chosen if name not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)}")
    for name in chosen:
        requires = METHODS[name].requires
        if requires is None:
            continue
        try:
            importlib.import_module(requires)
        except ImportError as exc:
            raise ValueError(
                f"method {name!r} needs {requires}, which does not import ({exc}); build the C core "
                "with `pip install .`, or leave the method out with --methods"
            ) from exc
    return [METHODS[name] for name in dict.fromkeys(chosen)]
