"""A rounded (bevelled) top edge, measured as far as the data allows (docs/measurements.md, Validity;
docs/sole-benchmark.md, sixth round): how far the sole's edge lies beyond where its depth ends, and how the
top falls across the edge towards it.

Such a sole is refused (edge_checks.check_edge_profile); this module says by how much, in the refusal's
words, and is the outline part of measuring it one day. What is known, and why it is still refused:

- The outline. Seen from above, the widest extent of a top that rounds off into a vertical wall is the wall.
  A camera on the inner side of the edge (both cameras, all round a convex sole: they look down on its middle)
  sees the sole's silhouette where its ray grazes the curve, at or below the lowest height that depth reached
  at the outline (the curve goes on falling beyond it, unmeasured) and above the table. Each camera's
  silhouette projected at those two heights bounds the edge (`silhouette_bounds`). The inner bound is where
  the depth already ends (0.0-0.1 mm beyond it, median, on the matrix's rounded soles); projected at the
  true height of the wall's top the silhouettes lie 0.1-0.4 mm (median) inside the true edge, where the depth
  outline lies 0.4-1.0 mm inside, but that height is not measured: it is the curve's unmeasured part.
- The surface. The glue line 2 mm inside the true edge lies on the curve, 20-37 degrees steep for 3-5 mm of
  radius. The stereo cloud there is 0.4-0.6 mm low; local fits on it across the edge (quadratic or linear,
  pooled along the outline or not) and the image patch fits miss the true normal by more than the 5 degree
  tolerance at 80-95 % of the glue line's points (12-15 degrees too flat in the median on two of three soles),
  where a quadratic over +-1.5 mm across the edge fitted to the true heights is within it at 95 %: the data,
  not the fit, falls short. So no valid glue path can be given, and the check refuses.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.vision.checks import MIN_TESTABLE
from cellctl.vision.defaults import GLUE_OFFSET_MM
from cellctl.vision.edge_checks import EDGE_OUTER_MM, edge_offset_pair, mean_of_known, top_falls
from cellctl.vision.footprint import Footprint
from cellctl.vision.image_edge import projections, table_level
from cellctl.vision.reconstruction import Reconstruction

FALL_AT_MM = (EDGE_OUTER_MM, 1.0, 1.5, 2.0, 2.5, 3.0)  # distances in from the outline where the fall is read


def fall_profile(fall: np.ndarray) -> np.ndarray:
    """The median of `edge_checks.top_falls` round the outline per distance (K), NaN where fewer than MIN_TESTABLE of the points
    are known: a rounded edge runs round the sole, a single bad patch does not move the median."""
    known = np.isfinite(fall)
    enough = known.mean(axis=0) >= MIN_TESTABLE
    median = np.full(fall.shape[1], np.nan)
    for k in np.flatnonzero(enough):
        median[k] = float(np.median(fall[known[:, k], k]))
    return median


def profile_tilt_deg(profile: np.ndarray, at_mm: float, at: tuple[float, ...] = FALL_AT_MM) -> float:
    """How steeply the pooled profile falls outward at `at_mm` from the outline (degrees from horizontal): its
    slope over the known distances (central differences, numpy.gradient) interpolated there; NaN if fewer than
    two are known."""
    known = np.isfinite(profile)
    if np.count_nonzero(known) < 2:
        return float("nan")
    where = np.array(at)[known]
    slope = -np.gradient(profile[known], where)
    return float(np.degrees(np.arctan(np.interp(at_mm, where, slope))))


def silhouette_bounds(
    outline: np.ndarray,
    outward: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    cameras: list[tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]],
    table_level: Footprint | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per outline point: between which distances beyond it (mm along the outward normal) the cameras'
    silhouettes put the sole's edge, NaN where no camera shows a clear edge.

    A silhouette is a ray; where it meets the sole is not measured on a curve that goes on falling beyond the
    depth. Projected at the height where depth ends (the measured top EDGE_OUTER_MM inside; the median round
    the outline where unknown) and at the table's height, the nearer reading is the inner bound and the other
    the outer one (module doc); each bound is the mean of the cameras that show a clear edge at both heights. cameras: per camera its change
    mask and its table -> pixel projection (image_edge.projections).
    """
    level = surface_height(outline - EDGE_OUTER_MM * outward)
    if not np.any(np.isfinite(level)):
        unknown = np.full(len(outline), np.nan)
        return unknown, unknown
    level = np.maximum(np.where(np.isfinite(level), level, np.nanmedian(level)), 0.0)

    zero = np.zeros(len(outline))
    low, high = [], []
    for changed, to_pixel in cameras:
        at_level = edge_offset_pair(outline, outward, level, changed, to_pixel, table_level)[0]
        at_table = edge_offset_pair(outline, outward, zero, changed, to_pixel, table_level)[0]
        # A camera on the inner side reads nearer at the depth's level; one that sees the wall (the foot at the
        # table is its edge) reads nearer at the table: the nearer reading is the inner bound either way.
        both = np.isfinite(at_level) & np.isfinite(at_table)
        low.append(np.where(both, np.minimum(at_level, at_table), np.nan))
        high.append(np.where(both, np.maximum(at_level, at_table), np.nan))
    return mean_of_known(np.vstack(low)), mean_of_known(np.vstack(high))


def describe(profile: np.ndarray, bounds: tuple[np.ndarray, np.ndarray] | None, glue_offset_mm: float) -> str:
    """The rounded edge in numbers, for the refusal: between which distances beyond the depth's end the images
    put the edge (`silhouette_bounds`), and the fall and slope the depth shows under the glue line
    (`glue_offset_mm` inside the inner bound)."""
    words = []
    beyond = 0.0
    if bounds is not None:
        inner, outer = bounds
        if min(np.count_nonzero(np.isfinite(inner)), np.count_nonzero(np.isfinite(outer))) >= MIN_TESTABLE * len(inner):
            beyond = max(float(np.nanmedian(inner)), 0.0)
            words.append(
                f"the images put the edge {beyond:.1f}-{max(float(np.nanmedian(outer)), beyond):.1f} mm beyond where "
                "depth ends (medians round the outline; where in that range depends on the curve's unmeasured part)"
            )
    at = max(glue_offset_mm - beyond, FALL_AT_MM[0])
    tilt = profile_tilt_deg(profile, at)
    known = np.isfinite(profile)
    if np.isfinite(tilt) and np.any(known):
        fall = float(np.interp(at, np.array(FALL_AT_MM)[known], profile[known]))
        words.append(
            f"{glue_offset_mm:g} mm inside the edge the measured top has fallen {max(fall, 0.0):.1f} mm and slopes "
            f"{max(tilt, 0.0):.0f} degrees outward, a curve whose slope depth does not give within the glue normals' "
            "tolerance"
        )
    return "; ".join(words)


def detail(
    reconstruction: Reconstruction,
    outline: np.ndarray,
    outward: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    glue_offset_mm: float = GLUE_OFFSET_MM,
) -> str:
    """`describe` for a reconstruction's outline (points 1 mm apart, closed): the silhouettes' bounds where a
    taught table gave both change masks, the fall profile always."""
    profile = fall_profile(top_falls(outline, outward, surface_height, FALL_AT_MM))
    left, right = reconstruction.changed_left, reconstruction.changed_right
    bounds = None
    if left is not None and right is not None and reconstruction.calibration is not None:
        (left_pixel, _), (right_pixel, _) = projections(reconstruction)
        cameras = [(left, left_pixel), (right, right_pixel)]
        bounds = silhouette_bounds(outline, outward, surface_height, cameras, table_level(reconstruction))
    return describe(profile, bounds, glue_offset_mm)
