"""Stereo matching, the C core's only door: everything else in cellctl reaches `csrc/` through here.

from cellctl.stereo import StereoMatcher
disp = StereoMatcher(min_disparity=0, num_disparities=64).compute(left, right)
"""

import os

# The core's OpenMP threads sleep instead of spinning while they wait at a barrier: the matcher shares
# the cell's two cores with the service's other threads, and a spinning waiter holds the core the
# thread it waits for needs (measured under load: a Teddy match on 2 threads took 1.6 times as long
# as on 1 thread with spinning, the same without). libgomp reads this when the core is loaded; an
# OMP_WAIT_POLICY set by the user wins.
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

from cellctl.stereo.matcher import (  # noqa: E402 (after the setting above)
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
from cellctl.stereo.params import DISP_SCALE  # noqa: E402

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
