"""Where both cameras see a wall and their masks cannot say whether they end at its foot or at its top edge: the
image about each camera's foot reading says it.

A camera that sees the sole's wall has a mask edge that is either the wall's foot on the table (a wall that
differs from the table: a black wall on a grey table) or the top edge (a wall lit so that the change test counts
it as table: tall white and rimmed walls), the same ray at two heights (cellctl.vision.image_edge). Where the
other camera sees the wall as well and no foot reading of one agrees with the other's top reading
(`image_edge.unpaired`: a side of the sole running along the baseline, both cameras seeing it at the same
angle), `stereo_offsets` takes each camera's reading nearer the outline, the top one. That passed matrix sole
39073 (black, square heel, the right camera 18 % brighter) with its outline 1.1 mm beyond the foot over 4 mm
and a glue point 1.06 mm off its inset: both feet read 0.9-1.6 mm inside, both tops on the outline
(docs/sole-benchmark.md, forty-first round).

What tells the two apart is the image on the table plane just inside each camera's foot reading. One ray meets
the foot and, a slant further in, the top edge's height; so if the mask ended at the foot, the band between the
foot reading and where the top edge then projects (the slant: the camera's top reading less its foot reading) is
the wall's face, and the top lies inward of it; if it ended at the top edge, that band is the top itself. The
image beyond the mask's edge cannot tell them: it shows the table either way, since that is what the change test
found there. So where a camera shows a band about its foot reading darker or brighter than both the top further
in and the table beyond (39073's black wall reads 50 DN darker than its top, 10-15 below the table), the foot
readings are the edge, and the edge-offset check reads them. A check only: it can refuse an outline, never move
one or pass one the masks refuse; a wall shaded between its top and the table stays unresolved, as before.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import cv2
import numpy as np

from cellctl.vision.image_edge import Readings, unpaired
from cellctl.vision.shadow import photometry

# The profile on the table plane read from TOP_SPAN_MM inward of where the top edge would project (the foot reading
# less the camera's slant) to BEYOND_MM past the foot reading, BAND_STEP_MM apart: the top's level is its first
# TOP_SPAN_MM, the table's its last BEYOND_MM / 2.
TOP_SPAN_MM = 0.75
BEYOND_MM = 1.0
BAND_STEP_MM = 0.25
# A wall's face: between them, two or more samples (0.5 mm) beyond both levels, darker than both or brighter than
# both, by this share of the top's contrast to the table and this many noise sigmas. Where the mask ended at the
# top edge the profile falls from the top to the table-like face monotonically (blurred over ~0.5 mm, texture of
# a few DN); 39073's black wall reads 50 DN darker than its top and 10-15 below the table.
WALL_CONTRAST_SHARE = 0.25
WALL_SIGMAS = 4.0
WALL_SAMPLES = 2


def wall_inside(
    current: np.ndarray,
    reference: np.ndarray,
    changed: np.ndarray,
    to_pixel: Callable[[np.ndarray], np.ndarray],
    ring: np.ndarray,
    outward: np.ndarray,
    foot: np.ndarray,
    top: np.ndarray,
) -> np.ndarray:
    """Per outline point: whether one camera's grey image shows a wall's face about its foot reading `foot` (mm along
    `outward`) on the table plane: a band of WALL_SAMPLES or more samples between the top (inward of where the top
    edge would project if the foot were the edge: `top` - `foot` further in, the same ray at the two heights) and the
    table beyond the foot, darker or brighter than both (WALL_CONTRAST_SHARE of their contrast, WALL_SIGMAS noise
    sigmas). No: where a reading is unknown or the camera's slant is negative (it does not see the wall)."""
    _, sigma = photometry(current, reference, changed)
    slant = top - foot
    known = np.isfinite(foot) & np.isfinite(top) & (slant >= 0.0)
    base = np.where(known, foot, 0.0) - np.where(known, slant, 0.0) - TOP_SPAN_MM
    length = np.where(known, slant, 0.0) + TOP_SPAN_MM + BEYOND_MM
    count = int(np.ceil(float(np.max(length, initial=0.0)) / BAND_STEP_MM)) + 1
    steps = np.arange(count) * BAND_STEP_MM
    profile = _samples(current, to_pixel, ring, outward, base, steps)
    index = np.arange(count)[None, :]
    top_part = index < int(round(TOP_SPAN_MM / BAND_STEP_MM))
    end = np.round(length / BAND_STEP_MM).astype(int)[:, None]
    table_part = (index <= end) & (index > end - int(round(0.5 * BEYOND_MM / BAND_STEP_MM)))
    between = ~top_part & (index <= end - int(round(BEYOND_MM / BAND_STEP_MM)) + 1)
    with np.errstate(invalid="ignore"):
        top_level = _median_where(profile, top_part)
        table_level = _median_where(profile, table_part)
        margin = np.maximum(WALL_CONTRAST_SHARE * np.abs(top_level - table_level), WALL_SIGMAS * sigma)
        darker = profile < (np.minimum(top_level, table_level) - margin)[:, None]
        brighter = profile > (np.maximum(top_level, table_level) + margin)[:, None]
        band = np.maximum(np.sum(darker & between, axis=1), np.sum(brighter & between, axis=1))
    return known & (band >= WALL_SAMPLES)


def _median_where(values: np.ndarray, where: np.ndarray) -> np.ndarray:
    """Per row the median of `values` where `where` (NaN where none)."""
    chosen = np.where(np.broadcast_to(where, values.shape), values, np.nan)
    with warnings.catch_warnings():  # a row off the image: all NaN, its median NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(chosen, axis=1)


def _samples(
    image: np.ndarray,
    to_pixel: Callable[[np.ndarray], np.ndarray],
    ring: np.ndarray,
    outward: np.ndarray,
    base: np.ndarray,
    steps: np.ndarray,
) -> np.ndarray:
    """The image on the table plane at `base` + `steps` mm along `outward` from each outline point (N x len(steps);
    NaN off the image)."""
    along = base[:, None] + steps[None, :]
    xy = ring[:, None, :] + along[..., None] * outward[:, None, :]
    points = np.concatenate([xy.reshape(-1, 2), np.zeros((xy.shape[0] * xy.shape[1], 1))], axis=1)
    pixels = to_pixel(points).astype(np.float32)
    values = cv2.remap(
        np.asarray(image, np.float32),
        pixels[:, 0].reshape(1, -1),
        pixels[:, 1].reshape(1, -1),
        cv2.INTER_LINEAR,
        borderValue=-1.0,
    ).reshape(along.shape)
    return np.where(values >= 0.0, values, np.nan)


def feet_confirmed(readings: tuple[Readings, Readings], wall_left: np.ndarray, wall_right: np.ndarray) -> np.ndarray:
    """Per outline point: the masks cannot tell foot from top there (`unpaired`) and a camera shows a wall's face about
    its foot reading (`wall_inside`, innermost readings): the feet are the edge. One camera suffices: the wall is the
    same for both, and the one that sees it more steeply shows the wider band (39073's right camera, 18 % brighter,
    shows its black wall one sample deep, its left camera four)."""
    return unpaired(readings) & (wall_left | wall_right)


def read_feet(
    offsets: tuple[np.ndarray, np.ndarray], readings: tuple[Readings, Readings], confirmed: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """Both cameras' offsets (`stereo_offsets`, k = 0 innermost, 1 outermost) with their foot readings where
    `confirmed` (`feet_confirmed`)."""
    (foot_l, _, _), (foot_r, _, _) = readings
    return np.where(confirmed, foot_l[k], offsets[0]), np.where(confirmed, foot_r[k], offsets[1])
