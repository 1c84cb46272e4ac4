"""Stereo matching, the C core's only door: everything else in cellctl reaches `csrc/` through here.

from cellctl.stereo import StereoMatcher
disp = StereoMatcher(min_disparity=0, num_disparities=64).compute(left, right)
"""

from cellctl.stereo.matcher import (
    DISP_SCALE,
    INVALID,
    MatcherParams,
    StereoMatcher,
    StereoResult,
    census_transform,
    cost_volume,
    make_params,
    postprocess,
    select,
    to_float,
)

__all__ = [
    "DISP_SCALE",
    "INVALID",
    "MatcherParams",
    "StereoMatcher",
    "StereoResult",
    "census_transform",
    "cost_volume",
    "make_params",
    "postprocess",
    "select",
    "to_float",
]
