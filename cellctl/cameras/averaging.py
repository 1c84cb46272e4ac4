"""Several exposures of the still scene averaged: the sensor's noise falls by sqrt(n) for the sole's surface fits.

Why: on a black sole the top's texture is a few grey levels deep and the sensor's noise about 1.3 DN, so the
surface's sub-pixel image fits (cellctl.vision.subpixel), which give every height and glue point, are
noise-limited there. With one exposure the glue heights' expected error on black soles lay at 0.28-0.46 mm against
the 0.28 mm a 1 mm tolerance allows, and those soles were refused (docs/sole-benchmark.md, twenty-sixth round);
four exposures halve the noise. The sole lies still on the table while the cell measures it, so the exposures
differ by the sensor's noise alone.

Only the surface fits read the mean (`StereoFrame.averaged`); the matcher, the change against the taught table and
so the outline read the last exposure, as before: their thresholds were set on single exposures. On the mean the
change test's residual noise reads at its floor and its masks moved (lengths 0.15-0.2 mm longer on white and grey
soles), and with that floor restored, or with only the matcher on the mean, one black sole was published with a
glue point 1.11 mm off its inset beside its contact shadow (docs/sole-benchmark.md, twenty-sixth round).

Where an exposure differs from the last one by more than the noise (the sole still settling after it was laid
down, the fixture shaken), the mean would blur the surface: it is left out (`still_frames`), and the frame's info
says how many were averaged and how many were left out.
"""

from __future__ import annotations

import numpy as np

from cellctl.cameras.base import StereoFrame
from cellctl.vision.teach import average_exposures
from cellctl.vision.workers import worker

# Two exposures agree where no more than MAX_MOVED_SHARE of their pixels differ by more than MOTION_SIGMAS times
# the difference's own robust spread (and at least MIN_MOTION_DN, the 8-bit steps). The spread is the median
# pixel's, and on 8-bit differences it reads low (1.48 DN where the mean pixel's is ~2), while a white sole's
# pixels carry 1.7 x the median's noise (shot noise): at 6 spreads 0.1-0.13 % of a still white sole's image
# exceeded it (10 of 168 still matrix scenes taken for moved); at 8, a white pixel needs 3.4 of its own sigmas
# (~0.02 % of the image). A sole that moved by one pixel changes its whole edge by tens of DN (~0.15-0.3 % of a
# 1280 x 1024 image for a white sole).
MOTION_SIGMAS = 8.0
MIN_MOTION_DN = 4.0
MAX_MOVED_SHARE = 0.001
MOTION_STRIDE = 8  # every 8th row and column (~20000 pixels of 1280 x 1024): a moved edge's share stays ~0.2 %
# Two exposures of one still view differ by the sensor's noise, times sqrt(2): a spread of ~2 DN on the simulated
# sensors, ~10 DN with their heavy noise. A wider spread, or the whole image brighter or darker by more than this,
# is another view (a lamp switched, another scene), whatever its own spread would excuse.
MAX_SAME_VIEW_DN = 16.0


def frames_agree(first: np.ndarray, second: np.ndarray) -> bool:
    """Whether two exposures (BGR or grey uint8) of one camera show the same still scene (not if their sizes differ)."""
    if first.shape != second.shape:
        return False
    a = _grey(first[::MOTION_STRIDE, ::MOTION_STRIDE]).astype(np.float32)
    b = _grey(second[::MOTION_STRIDE, ::MOTION_STRIDE]).astype(np.float32)  # (green: the grey's largest weight)
    difference = b - a
    centre = float(np.median(difference))  # a light's flicker moves the whole image a little
    spread = 1.4826 * float(np.median(np.abs(difference - centre)))
    if abs(centre) > MAX_SAME_VIEW_DN or spread > MAX_SAME_VIEW_DN:
        return False
    limit = max(MOTION_SIGMAS * spread, MIN_MOTION_DN)
    return float(np.mean(np.abs(difference - centre) > limit)) <= MAX_MOVED_SHARE


def still_frames(frames: list[StereoFrame]) -> list[StereoFrame]:
    """The frames (in order) whose left image agrees with the last frame's (`frames_agree`), the last included: a
    scene that moves moves in both cameras' views, and one comparison per frame costs the cycle ~1 ms."""
    last = frames[-1]
    return [f for f in frames[:-1] if frames_agree(f.left, last.left) and f.right.shape == last.right.shape] + [last]


def average_frames(frames: list[StereoFrame]) -> StereoFrame:
    """The last of `frames` (one or more consecutive exposures) with the mean of the still ones among them as its
    `averaged` pair (None if only the last is still); its info is the last frame's with "averaged_frames" (and
    "moved_frames" where some were left out)."""
    if not frames:
        raise ValueError("averaging needs one or more frames")
    still = still_frames(frames)
    last = still[-1]
    info = dict(last.info, averaged_frames=len(still))
    if len(still) < len(frames):
        info["moved_frames"] = len(frames) - len(still)
    if len(still) == 1:  # its own mean, if it brings one (a replayed cycle of the image log)
        return StereoFrame(last.left, last.right, last.t_left, last.t_right, info, last.averaged)
    # The right camera's mean on the second core (numpy's loops release the GIL): ~8 ms of a cycle's ~16.
    right = worker("average").submit(average_exposures, [f.right for f in still])
    averaged = average_exposures([f.left for f in still]), right.result()
    return StereoFrame(last.left, last.right, last.t_left, last.t_right, info, averaged)


def _grey(image: np.ndarray) -> np.ndarray:
    """A grey image's own values; a BGR image's green channel (motion shows in any channel)."""
    return image if image.ndim == 2 else image[..., 1]
