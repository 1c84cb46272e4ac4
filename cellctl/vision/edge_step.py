"""The sole's step in the images themselves, against the outline: a dark band at the sole's foot taken for sole.

The outline's other image checks read the change masks against the taught table, so they cannot see a band of
the table that both masks took for sole: a shadow right at the foot of a low black sole (a low lamp's umbra,
darker than the rest of its shadow; the dark band a physically based renderer draws where the sole hides the
room's light) is darker than the taught table in both views, too narrow for the texture vote and for stereo to
tell from the sole (1-2 mm, a low sole's disparity only 1-2 px above the table's), and the matcher carries the
sole's height across it. The outline then runs along the band's outer edge, 1-2 mm out, and the glue line with it
(matrix sole 39016, shadows, a right camera 15-20 % brighter: 1.8 mm out over 18 mm, refused by the right image
at 4 consecutive points where at most 2 pass, and published 1.69 mm out when its images were JPEG-compressed).

What the raw images still show is the sole's own step: sampled along each outline point's outward normal at the
height of that camera's silhouette (the top edge's), the strongest change of brightness over half a millimetre
lies at the outline on every measured sole, and 1.5-2 mm inside it beside such a band, where the band's outer edge
is a weak step. Where both cameras see a step inside the outline clearly stronger than any at it, along a
stretch, the outline there is not the sole's edge.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from cellctl.errors import FailureKind
from cellctl.images import grey_f32
from cellctl.vision.checks import CheckFailure
from cellctl.vision.closed_path import closed_runs, normal_samples

STEP_SAMPLES_MM = np.arange(-4.0, 2.0 + 1e-9, 0.25)  # along the outward normal, from inside the outline
STEP_SPAN = 2  # samples: a step is the brightness change over 0.5 mm
INNER_STEP_MM = (-3.0, -0.75)  # where a step lies inside the outline (its midpoint), beyond the outline's scatter
AT_OUTLINE_MM = (-0.5, 0.75)  # where the step of an outline on the sole's edge lies
# A step inside counts when it is this many times the strongest at the outline and at least this many grey levels
# (~4 sigma of the sensor's noise after the 0.5 mm difference of two samples).
INNER_STEP_RATIO = 1.5
INNER_STEP_MIN_DN = 6.0
INNER_STEP_RUN = 5  # consecutive outline points (1 mm apart) where both cameras show it: a stretch, not a speck


def step_profiles(
    ring: np.ndarray,
    outward: np.ndarray,
    level: np.ndarray,
    image: np.ndarray,
    to_pixel: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """Grey levels (float32, outline points x STEP_SAMPLES_MM) of `image` along each outline point's outward
    normal at the height `level` (per point; table points -> rectified pixels by `to_pixel`); NaN off the image."""
    points = normal_samples(ring, outward, STEP_SAMPLES_MM, level)
    pixels = to_pixel(points.reshape(-1, 3)).astype(np.float32).reshape(*points.shape[:2], 2)
    grey = grey_f32(image)
    return cv2.remap(grey, pixels[:, :, 0], pixels[:, :, 1], cv2.INTER_LINEAR, borderValue=float("nan"))


def inner_steps(profiles: np.ndarray) -> np.ndarray:
    """Per outline point: whether its profile's strongest step inside the outline (INNER_STEP_MM) clearly exceeds
    every step at it (AT_OUTLINE_MM), with what lies between them no brighter than both sides (a band brighter than
    the sole and the table is no shadow: the narrow top of a light rim on a black sole, 47038 of set 47000); False
    where the profile leaves the image."""
    change = np.abs(profiles[:, STEP_SPAN:] - profiles[:, :-STEP_SPAN])
    middle = 0.5 * (STEP_SAMPLES_MM[STEP_SPAN:] + STEP_SAMPLES_MM[:-STEP_SPAN])
    inner = (middle >= INNER_STEP_MM[0]) & (middle <= INNER_STEP_MM[1])
    at = (middle >= AT_OUTLINE_MM[0]) & (middle <= AT_OUTLINE_MM[1])
    known = np.all(np.isfinite(profiles), axis=1)
    safe = np.where(np.isfinite(change), change, 0.0)
    inside_change = np.where(inner[None, :], safe, -1.0)
    strongest = np.argmax(inside_change, axis=1)
    strongest_inside, strongest_at = inside_change[np.arange(len(profiles)), strongest], safe[:, at].max(axis=1)
    clear = known & (strongest_inside > INNER_STEP_RATIO * strongest_at) & (strongest_inside >= INNER_STEP_MIN_DN)
    return clear & ~_brighter_band(profiles, middle[strongest])


def _brighter_band(profiles: np.ndarray, step_mm: np.ndarray) -> np.ndarray:
    """Per profile: whether the samples between its step at `step_mm` and the outline are brighter on average than
    both the 1 mm further in and the 0.5-1.5 mm beyond the outline."""
    samples = np.broadcast_to(STEP_SAMPLES_MM[None, :], profiles.shape)
    step = step_mm[:, None]

    def mean(mask: np.ndarray) -> np.ndarray:
        return np.where(mask, profiles, 0.0).sum(axis=1) / np.maximum(mask.sum(axis=1), 1)

    band = mean((samples > step) & (samples <= 0.0))
    inside = mean((samples < step) & (samples >= step - 1.0))
    outside = mean((samples >= 0.5) & (samples <= 1.5))
    return band > np.maximum(inside, outside)


def check_inner_step(left: np.ndarray, right: np.ndarray) -> CheckFailure | None:
    """Both cameras' `inner_steps` along the outline (closed): a run of INNER_STEP_RUN points or more where both show
    the sole's step inside the outline is refused."""
    runs = [run for run in closed_runs(left & right) if len(run) >= INNER_STEP_RUN]
    if not runs:
        return None
    longest = max(runs, key=len)
    return CheckFailure(
        FailureKind.OUTLINE_INCONSISTENT,
        f"both images show the sole's edge as a step inside the outline, stronger than any at it, along "
        f"{len(longest)} mm from outline point {int(longest[0])} (a stretch of {INNER_STEP_RUN} mm refuses): the "
        "outline there follows a dark band beside the sole (a shadow at its foot), not the sole's edge; light the "
        "table so that no shadow falls at the sole's foot",
    )
