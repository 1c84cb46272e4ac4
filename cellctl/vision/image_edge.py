"""The sole's edge placed from the images: the depth-based outline moved out onto the edge both cameras'
silhouettes (change masks against the taught table) show, each projected at the height where that camera's
silhouette lies (docs/measurements.md, Footprint), read as the edge-offset check of
cellctl.vision.outline_checks reads them (`stereo_offsets`, innermost and outermost of equally good steps).

What it corrects: the depth outline stops short of a weakly textured (black) top edge, by 0.6-1.4 mm on the
matrix soles (up to 1.9 mm on a few fresh ones). Where the census window straddles the step along an edge near
the epipolar lines, the sole's and the table's disparities cost alike and the uniqueness test drops the last mm;
next to a textured table the matcher drags the table's disparity onto the edge, so that band of the sole lies on
table-level cells, which the innermost reading excuses (it stops on the outline) and the outermost reads as the sole.

Guards: both cameras agree (each at its own silhouette height), the move is 0.5-2 mm (EDGE_MOVE_MAX_MM; a dark cast
shadow's edge lies 2-3 mm out: such a point is not moved and the check refuses it), the innermost readings do not
put the edge inside, and depth is silent on the way (`depth_silent`: no raw table-level depth in the
crossed band; a contact shadow on textured table is measured there). After a move the edge-offset check
compares the outline with the masks it was moved onto, so there it refuses only errors beyond the cap or
where the cameras disagree; the depth-step and right-image tests stay independent of the move.

Inward moves (PLACE_EDGE_INWARD) take the outline off a narrow blob of depth beyond the edge, per point where both
cameras agree, only over whole stretches and only over stretches no longer than two census windows: a longer
stretch beyond both silhouettes is the matcher's disparity smeared outward along the edge, which smears the
heights inside it as well, so there the outline stays and the edge-offset check refuses it (`edge_shift`).

A camera's silhouette is the top edge where the sole hides its wall from it (the wall faces away): there
the edge lies where the silhouette's ray meets the top edge's measured height. Where a camera sees the wall,
its silhouette is the foot or, for a wall lit like the table, the top edge, which one camera cannot tell
apart: `stereo_offsets` takes the one the other camera's unambiguous reading confirms, and where both cameras
see the wall, the foot or top reading of each that agree with each other (`_paired`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellctl.vision.closed_path import (
    closed_runs,
    outward_normals,
    resample_closed,
    run_lengths,
    running_median,
    smooth_along,
)
from cellctl.vision.edge_checks import (
    NOTCH_MAX_HALF_CHORD_MM,
    edge_offset_pair,
    offset_median,
)
from cellctl.vision.footprint import Footprint
from cellctl.vision.reconstruction import SOLE_MATCHER_PARAMS, Reconstruction
from cellctl.vision.surface import SoleSurface

EDGE_HEIGHT_IN_MM = 3.0  # the top edge's height is read this far inside the outline, over a disc of this radius
EDGE_RISE_REACH = 3  # outline points (~1 mm apart) either side of each over which the top's rise is taken
EDGE_RISE_MIN_MM = 0.3  # a rise towards the outline under this (a slope of 0.1) is the heights' noise
PLACE_EDGE_FROM_IMAGES = True  # outward moves; the module docstring says what guards them
# Inward moves: off narrow blobs of depth beyond the edge (a local mismatch a few mm wide), where both cameras
# agree point by point over the whole blob (`edge_shift`). Measured on the matrices (docs/sole-benchmark.md,
# seventh round "inward7"): 2027, 2036, 2051 and held-out 3026 newly right. The first version (offset6: running
# medians, any length) made two soles valid and wrong that no other check sees, both left alone now: 2070's 25 mm
# stretch 0.5-1.1 mm beyond a black pointed toe is smeared depth, and the cloud within 3 mm inside it lies
# 1.2-1.8 mm high (glue height 1.27 mm off with the outline right); and 3065's narrow spike, where the
# nearer-the-outline reading of two cameras that both see the wall (`_paired`) had hidden it from the check.
PLACE_EDGE_INWARD = True
# Outward moves on one camera's evidence, only to fill a notch in the outline that the other camera's change
# mask left (`notch_fill`; docs/sole-benchmark.md, session 8 "edge8": held-out 3029, 3073, 4029, 4041).
FILL_NOTCHES = True
# The outline's course across a notch (`_rim`) is fitted to this many points (1 mm apart) on either side: 3 mm of
# outline fixes a quadratic's curvature against the ~0.2 mm scatter of the outline's points.
NOTCH_RIM_POINTS = 3
# A notch is local: the rim's chord no longer than the notch check's widest window (edge_checks, 14 mm).
NOTCH_MAX_CHORD_MM = 2 * NOTCH_MAX_HALF_CHORD_MM
EDGE_MOVE_MIN_MM = 0.5  # a sharp edge's offsets scatter by ~0.2 mm in the images: smaller is no evidence
# A dent is a notch to fill once the outline lies inside its own course by more than the readings' scatter. Not only
# beyond the edge-offset check's limit (0.8 mm, sessions 8-30): the notch check refuses a sharp dent shallower than
# that (standard sole 15, taught: 0.7 mm below its course over 2 mm, 0.9 by the notch check's chords, 1.4 mm inside
# the true edge), which one camera showed 0.6-0.9 mm further out (docs/sole-benchmark.md, thirtieth round).
NOTCH_MIN_DEPTH_MM = EDGE_MOVE_MIN_MM
EDGE_MOVE_AGREE_MM = 0.5  # both cameras' local edges this close (a shadow or a texture line fools one mask)
EDGE_MOVE_SMOOTHING_MM = 1.5
# The depth outline's own errors the move corrects: ~1 mm (a dark top edge's last mm without depth; a textured
# table's disparity dragged onto a black edge; a depth step fattened past the masks), up to 1.6-1.9 mm on the fresh
# sets (a black cusped toe's last mm on the grey table, 39082; blobs of depth 1.9 mm beyond a grey sole under
# shadows, 43039, and a plain black one, 49023: both cameras agreeing, all three right once moved; 1.5 until session
# 41, docs/sole-benchmark.md, fortieth round). The masks' errors that both cameras share are larger (a cast shadow's
# edge 2-3 mm beyond the sole, where the shadow band has not already been taken out of both masks,
# cellctl.vision.shadow_band): such a point is not moved. 2.5 and 3.0 gained one sole at most on older sets
# (docs/sole-benchmark.md: twenty-fourth round, "Rims" of session 9).
EDGE_MOVE_MAX_MM = 2.0
# Inward moves: a blob of depth beyond the edge is a local mismatch, about a census window wide (9 px, 3.5 mm at
# the default rig's 0.39 mm per pixel; `blob_length_mm`: two windows); the outline lies beyond the edge there by
# more than the readings' scatter (~0.2 mm, 0.25 mm steps). A longer such stretch is the sole's disparity smeared
# outward along its edge: on a black pointed toe the cloud within 3 mm inside such an edge lies 1.2-1.8 mm high
# (the top falls there, the smear does not), so the glue heights there are not the sole's and it is not moved.
SMEARED_EDGE_MM = 0.25
# A blob survives the footprint's 1 mm opening only if wider than 1 mm: two or more outline points (1 mm apart). A
# lone point where both cameras read 0.5-0.7 mm inside is the readings' scatter (0.25 mm steps), and was wrong on
# 2032 (the outline there already 0.8 mm short of the edge).
MIN_BLOB_POINTS = 2
BLOB_CENSUS_WINDOWS = 2.0
INWARD_SMOOTHING_MM = 0.75  # a blob's flanks are ~1 mm wide: the move no smoother than the depth outline itself
# The guard (`depth_silent`): a move must cross ground where depth measured nothing at the table's height, in a
# strip this wide along the outline, up to this far short of the proposed edge (the table is measured from there).
SILENT_STRIP_MM = 1.0
SILENT_SHORT_OF_EDGE_MM = 0.25
SILENT_STEP_MM = 0.125  # half a raster cell


def projections(
    reconstruction: Reconstruction,
) -> tuple[
    tuple[Callable[[np.ndarray], np.ndarray], np.ndarray], tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]
]:
    """Per camera (left, right): table points (N x 3) -> rectified pixels (N x 2), and its centre in the table
    frame. The reconstruction must come from a stereo cloud (a calibration)."""
    calib = reconstruction.calibration
    assert calib is not None
    to_camera = np.linalg.inv(reconstruction.camera_to_table)
    f, cx, cy, baseline = calib.focal_px, calib.P1[0, 2], calib.P1[1, 2], calib.baseline_mm

    def pixel(shift: float) -> Callable[[np.ndarray], np.ndarray]:
        def project(table: np.ndarray) -> np.ndarray:
            camera = table @ to_camera[:3, :3].T + to_camera[:3, 3]
            return np.column_stack(
                [f * (camera[:, 0] - shift) / camera[:, 2] + cx, f * camera[:, 1] / camera[:, 2] + cy]
            )

        return project

    right_centre = (reconstruction.camera_to_table @ np.array([baseline, 0.0, 0.0, 1.0]))[:3]
    return (pixel(0.0), reconstruction.camera_to_table[:3, 3]), (pixel(baseline), right_centre)


def table_level(reconstruction: Reconstruction) -> Footprint | None:
    """Cells whose measured points lie at the table's height (measured, not raised), if the depth step is known."""
    raised, measured = reconstruction.raised, reconstruction.measured_cells
    if raised is None or measured is None:
        return None
    return Footprint(measured.mask & (1 - raised.mask), raised.origin, raised.cell_mm)


def edge_heights(surface: SoleSurface, ring: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """The sole's top-edge height at each outline point of `ring` (closed, ~1 mm apart): read EDGE_HEIGHT_IN_MM
    inside (the median of the others where none; all NaN where none is known), and where the top rises towards the
    outline, carried on to it (`rise_to_outline`)."""
    near = surface.coarse_heights(ring - EDGE_HEIGHT_IN_MM * outward, EDGE_HEIGHT_IN_MM)
    if not np.any(np.isfinite(near)):
        return near
    far = surface.coarse_heights(ring - 2.0 * EDGE_HEIGHT_IN_MM * outward, EDGE_HEIGHT_IN_MM)
    edge_height = near + rise_to_outline(near, far)
    return np.where(np.isfinite(edge_height), edge_height, np.nanmedian(near))


def rise_to_outline(near: np.ndarray, far: np.ndarray) -> np.ndarray:
    """How much higher the top stands at each outline point than EDGE_HEIGHT_IN_MM inside it, where it rises towards
    the outline: the rise from twice that far in (`far`) to there (`near`), the running median over
    EDGE_RISE_REACH points either side (the heights' noise), where it exceeds EDGE_RISE_MIN_MM; 0 elsewhere.

    A camera that sees the top edge as its silhouette places the edge where its ray meets the edge's height, and
    the ray runs outward as it falls (0.4 mm per mm of height at a toe's tip). A toe spring lifts the top towards
    the tip: read 3 mm in, the edge's height was 1.8 mm low at the tip of a toe sprung 20 mm (`sprung-toe` beyond
    its range, /work/notes/s37/spring.py), the outline 0.8 mm beyond the tip, the length 1.1 mm long and the toe
    height 0.8 mm high (it lies on the steep top 10 % in from the tip: published wrong). A top falling towards its
    edge (a rounded edge, a sloped wall) is not carried on: its silhouette is not its top edge (rounded_edge)."""
    known = np.isfinite(near) & np.isfinite(far)
    rise = running_median(np.where(known, near - far, np.nan), EDGE_RISE_REACH, EDGE_RISE_REACH + 1)
    return np.where(rise > EDGE_RISE_MIN_MM, rise, 0.0)


Camera = tuple[np.ndarray, Callable[[np.ndarray], np.ndarray], np.ndarray]  # change mask, projection, centre
# One camera's readings (`_readings`): foot and top, each (innermost, outermost), and where it sees the wall.
Readings = tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], np.ndarray]


def camera_readings(
    ring: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    cameras: tuple[Camera, Camera],
    table_level: Footprint | None = None,
) -> tuple[Readings, Readings]:
    """Both cameras' foot and top readings along the outline (`stereo_offsets` reads them; so may a check)."""
    left, right = (_readings(ring, outward, edge_height, camera, table_level) for camera in cameras)
    return left, right


def unpaired(readings: tuple[Readings, Readings]) -> np.ndarray:
    """Per outline point: both cameras see the wall and no foot reading of one agrees with the other's top reading
    within EDGE_MOVE_AGREE_MM (innermost readings), where `stereo_offsets` takes each camera's reading nearer the
    outline (`_paired`): the masks alone cannot tell the foot from the top edge there."""
    (foot_l, top_l, wall_l), (foot_r, top_r, wall_r) = readings
    best = np.min(_mixed_apart(foot_l[0], top_l[0], foot_r[0], top_r[0]), axis=0)
    return wall_l & wall_r & ~(best <= EDGE_MOVE_AGREE_MM)


def _mixed_apart(foot_l: np.ndarray, top_l: np.ndarray, foot_r: np.ndarray, top_r: np.ndarray) -> np.ndarray:
    """Per outline point how far apart one camera's foot and the other's top reading lie (2 x N: left foot with
    right top, left top with right foot; inf where either is unknown)."""
    return np.stack([np.nan_to_num(np.abs(a - b), nan=np.inf) for a, b in ((foot_l, top_r), (top_l, foot_r))])


def _readings(
    ring: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    camera: Camera,
    table_level: Footprint | None,
) -> Readings:
    """One camera's mask edge read at the table (foot) and at the top edge's height (top), each (innermost,
    outermost), and where it sees the wall (its centre lies outward of the outline point)."""
    changed, to_pixel, centre = camera
    sees_wall = np.sum(outward * (centre[:2] - ring), axis=1) > 0
    foot = edge_offset_pair(ring, outward, np.zeros(len(ring)), changed, to_pixel, table_level)
    top = edge_offset_pair(ring, outward, np.maximum(edge_height, 0.0), changed, to_pixel, table_level)
    return foot, top, sees_wall


def _nearer(foot: np.ndarray, top: np.ndarray, to: np.ndarray | float) -> np.ndarray:
    """Per point the reading nearer `to` (NaN readings never nearer)."""
    foot_off = np.nan_to_num(np.abs(foot - to), nan=np.inf)
    return np.where(foot_off < np.nan_to_num(np.abs(top - to), nan=np.inf), foot, top)


def _paired(
    foot_l: np.ndarray, top_l: np.ndarray, foot_r: np.ndarray, top_r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Where both cameras see the wall: per point one camera's foot and the other's top reading, the pair that
    agrees best (both cameras look at the one edge); of equally good pairs the one nearer the outline. Readings
    of one kind share their bias (a foot reading lies inside the edge by however far up the wall the mask ends,
    for both cameras alike: tall white walls), so two foot or two top readings agreeing is no evidence; where
    no foot-and-top pair agrees within EDGE_MOVE_AGREE_MM, each camera's reading nearer the outline, as for one
    camera."""
    pairs = ((foot_l, top_r), (top_l, foot_r))
    apart = _mixed_apart(foot_l, top_l, foot_r, top_r)
    off = np.stack([np.nan_to_num(np.abs(a) + np.abs(b), nan=np.inf) for a, b in pairs])
    best = np.min(apart, axis=0)
    choice = np.argmin(np.where(apart <= best + 1e-9, off, np.inf), axis=0)  # readings are 0.25 mm steps: ties
    pick = np.arange(len(best))
    left = np.stack([a for a, _ in pairs])[choice, pick]
    right = np.stack([b for _, b in pairs])[choice, pick]
    none = ~(best <= EDGE_MOVE_AGREE_MM)
    return np.where(none, _nearer(foot_l, top_l, 0.0), left), np.where(none, _nearer(foot_r, top_r, 0.0), right)


def stereo_offsets(
    ring: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    cameras: tuple[Camera, Camera],
    table_level: Footprint | None = None,
    readings: tuple[Readings, Readings] | None = None,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Where each camera's silhouette puts the edge, in mm along the outward normal from each outline point:
    ((left, right) innermost, (left, right) outermost of equally good steps: edge_checks.edge_offset_pair; where
    the outermost finds no edge, unknown to the end of its search as beside a wide shadow, the innermost stands).

    The silhouette is the top edge where the sole hides its wall from the camera, read at its measured height.
    Where the camera sees the wall it is the wall's foot on the table, or the top edge again if the wall is lit
    like the table; one camera cannot tell the two apart (the same ray at two heights), so there the reading
    is the one nearer the other camera's unambiguous reading (its top edge, where the wall is hidden from it);
    where the other sees the wall too, of each camera's two the pair that agrees best (`_paired`).

    The nearer-the-outline rule alone reads in the outline's favour: with the outline 1 mm beyond a dark wall's
    foot, the top reading of the camera that sees that wall lies on the outline (the ray to the foot crosses
    the top's height ~1 mm further out) and was taken, so an outline 0.5-1 mm beyond a black pointed toe passed
    the edge-offset check with the other camera's correct -0.9 mm halved by the mean. Where both cameras see the
    wall it did the same: 3065's left top reading lay on a 1.4 mm spike of the outline (a second step of its
    mask) while its foot, -1.4 mm, agreed with the right camera's -1.1.
    readings: `camera_readings` of the same outline and cameras, where already read."""
    if readings is None:
        readings = camera_readings(ring, outward, edge_height, cameras, table_level)
    (foot_l, top_l, wall_l), (foot_r, top_r, wall_r) = readings

    def read(k: int) -> tuple[np.ndarray, np.ndarray]:
        both = _paired(foot_l[k], top_l[k], foot_r[k], top_r[k])
        result = []
        for foot, top, wall, other_top, other_wall, paired in (
            (foot_l[k], top_l[k], wall_l, top_r[k], wall_r, both[0]),
            (foot_r[k], top_r[k], wall_r, top_l[k], wall_l, both[1]),
        ):
            witness = np.where(other_wall, np.nan, other_top)
            by_other = np.where(np.isfinite(witness), _nearer(foot, top, witness), paired)
            result.append(np.where(wall, by_other, top))
        return result[0], result[1]

    inner, outer = read(0), read(1)
    left, right = (np.where(np.isfinite(o), o, i) for o, i in zip(outer, inner, strict=True))
    return inner, (left, right)


def edge_shift(
    left: np.ndarray,
    right: np.ndarray,
    silent: Callable[[np.ndarray], np.ndarray] | None = None,
    outer: tuple[np.ndarray, np.ndarray] | None = None,
    inward_too: bool = True,
    longest_blob_mm: float = float("inf"),
) -> np.ndarray:
    """How far to move each outline point along its outward normal (+: out, -: in), smoothed along the
    outline; 0 where the evidence does not hold.

    left, right: each camera's silhouette offsets (`stereo_offsets`, the innermost of equally good steps);
    outer: the same read outermost (`stereo_offsets`), as the edge-offset check reads them; without it
    the innermost readings stand for both.

    - Outward by the outermost readings (the depth stopped short: excused table-level samples beyond it are the
      sole's edge band the matcher dragged to the table's height): the mean of both cameras' local edges (running
      medians over EDGE_OFFSET_WINDOW_MM) where they agree within EDGE_MOVE_AGREE_MM and lie more than
      EDGE_MOVE_MIN_MM and at most EDGE_MOVE_MAX_MM from the outline, where the innermost do not put the edge
      inside and `silent` allows it.
    - Inward off a blob of depth beyond the edge (`inward_too`): per point (a blob is a few mm wide, a running
      median would keep most of it) the mean of both cameras' innermost readings where they agree within
      EDGE_MOVE_AGREE_MM, put the edge more than EDGE_MOVE_MIN_MM (at most EDGE_MOVE_MAX_MM) inside, and the
      outermost agree that it is inside (no changed band beyond the outline that could be the sole's); only
      where every point of the stretch that either camera puts beyond the edge qualifies (neighbouring readings
      agree: a camera that sees no blob at its end leaves it, and a move of the rest would leave a notch), and
      only where
      the blob is MIN_BLOB_POINTS or more points long and the outline lies beyond both silhouettes for no longer
      than `longest_blob_mm` (`blob_length_mm`; default
      any length): a longer
      stretch is the matcher's disparity smeared outward along the edge, which smears the heights inside it too
      (SMEARED_EDGE_MM), so there the outline stays and the edge-offset check refuses it.

    Where the two readings contradict each other (an edge inside and another beyond), the point stays.

    Beyond EDGE_MOVE_MAX_MM the point stays: no depth error of the kind the move corrects was found that large, and
    the masks' own errors are (a cast shadow's edge 2-3 mm out); the edge-offset check then refuses it.
    silent (proposed moves -> bool per point): whether depth is silent over each outward move (`depth_silent`);
    where it is not, the point stays, also after the smoothing, so the edge-offset check still judges it there."""
    outer_left, outer_right = (left, right) if outer is None else outer
    local_left, local_right = offset_median(left), offset_median(right)
    far_left, far_right = offset_median(outer_left), offset_median(outer_right)
    far = 0.5 * (far_left + far_right)
    out = (np.abs(far_left - far_right) <= EDGE_MOVE_AGREE_MM) & (far > EDGE_MOVE_MIN_MM) & (far <= EDGE_MOVE_MAX_MM)
    out &= (local_left > -EDGE_MOVE_MIN_MM) & (local_right > -EDGE_MOVE_MIN_MM)
    if silent is not None:
        out &= silent(np.where(out, far, 0.0))
    shift = np.where(out, smooth_along(np.where(out, far, 0.0), EDGE_MOVE_SMOOTHING_MM), 0.0)
    if not inward_too:
        return shift
    with warnings.catch_warnings():  # NaN readings compare False
        warnings.simplefilter("ignore", RuntimeWarning)
        point = 0.5 * (left + right)
        inward = (np.abs(left - right) <= EDGE_MOVE_AGREE_MM) & (point < -EDGE_MOVE_MIN_MM)
        inward &= (point >= -EDGE_MOVE_MAX_MM) & (outer_left < -EDGE_MOVE_MIN_MM) & (outer_right < -EDGE_MOVE_MIN_MM)
        either = (point < -EDGE_MOVE_MIN_MM) | (left < -EDGE_MOVE_MIN_MM) | (right < -EDGE_MOVE_MIN_MM)
        inward = _whole_stretches(inward & ~out, either)
    inward &= ~smeared_stretches(left, right, longest_blob_mm) & (run_lengths(inward) >= MIN_BLOB_POINTS)
    moved_in = np.where(inward, smooth_along(np.where(inward, point, 0.0), INWARD_SMOOTHING_MM), 0.0)
    return np.where(inward, moved_in, shift)


def smeared_stretches(left: np.ndarray, right: np.ndarray, longest_blob_mm: float) -> np.ndarray:
    """Per outline point (closed, 1 mm apart): on a stretch where the outline lies beyond both silhouettes (the
    cameras' mean reading more than SMEARED_EDGE_MM inside it) for longer than `longest_blob_mm`: the matcher's
    disparity smeared outward along the edge, which `edge_shift` does not move in and the edge-offset check
    judges point by point (edge_checks.agreed_offsets)."""
    with warnings.catch_warnings():  # NaN readings compare False
        warnings.simplefilter("ignore", RuntimeWarning)
        beyond = np.nan_to_num(0.5 * (left + right), nan=0.0) < -SMEARED_EDGE_MM
    return run_lengths(beyond) > longest_blob_mm


def notch_fill(
    ring: np.ndarray,
    outward: np.ndarray,
    inner: tuple[np.ndarray, np.ndarray],
    outer: tuple[np.ndarray, np.ndarray],
    silent: Callable[[np.ndarray], np.ndarray],
    raised: Footprint,
) -> tuple[np.ndarray, np.ndarray]:
    """How far to move each outline point out (0 where not) to fill a notch one camera's change mask left, and per
    point the camera whose edge it was moved to (0 left, 1 right; -1 where not moved).

    The depth outline keeps only the sole's points that the left camera's change mask marks
    (sole_region.change_split). Where that mask misses edge pixels, because the table behind them in the left
    view looks like the sole (held-out 3029: the sole at 57-61 DN, the taught table behind its edge at 54-55,
    beside 50 further in), the outline has a notch 1-2 mm deep and 3-5 mm wide. The right camera looks at other
    table pixels behind the sole's top edge and shows the edge where it is; the two cameras disagree and
    `edge_shift` leaves the point. A notch sharper than a sole's edge bends (edge_checks.check_outline_notch) is
    itself evidence against the camera that shows it, so here one camera's reading is taken where all of:

    - it puts the edge beyond the outline by more than EDGE_MOVE_MIN_MM, innermost and outermost reading alike
      (the move is by the nearer of the two), at every point of a stretch of consecutive such points; where
      both cameras fill a point, the nearer of their edges;
    - the outline across the stretch is a notch: it lies inside the course of the outline on either side
      (`_rim`: a quadratic through the points beyond the notch's flanks, so a convex or concave edge's own
      curvature is no notch) by more than NOTCH_MIN_DEPTH_MM somewhere, and the moved points stay within
      EDGE_MOVE_AGREE_MM of that course (the camera fills the notch; it makes no bulge: a shadow or a
      reflection that one camera's mask takes for the sole is not followed beyond the sole's course);
    - depth measured the sole's height over the band crossed (`raised` cells up to SILENT_SHORT_OF_EDGE_MM
      short of the new edge: the points were dropped by the mask, not missing from depth) and no point at the
      table's height (`silent`: a contact shadow on a textured table is measured there).

    The checks then judge the moved outline against both masks, except that the edge-offset check reads the
    filled points by the camera that filled them (`PlacedOutline.one_camera`): the other camera's mask has the
    notch there, which is why it was filled, and the mean of both read the miss as an error of half its depth (std20
    sole 9 taught: a notch 2 mm deep filled to within 0.2 mm of the true edge, refused for "1.1 mm inside")."""
    n = len(ring)
    move = np.zeros(n)
    by = np.full(n, -1)
    with warnings.catch_warnings():  # NaN readings compare False
        warnings.simplefilter("ignore", RuntimeWarning)
        for this in (0, 1):
            reading = np.minimum(inner[this], outer[this])
            beyond = reading > EDGE_MOVE_MIN_MM
            if not beyond.any() or beyond.all():
                continue
            alone = beyond & silent(np.where(beyond, reading, 0.0))
            fill = np.zeros(n)
            for idx in closed_runs(beyond):
                if not alone[idx].all():
                    continue
                rim = _rim(ring, idx)
                if rim is None:
                    continue
                depth = rim(ring[idx])  # + inside the rim's curve
                if depth.max() <= NOTCH_MIN_DEPTH_MM:
                    continue  # not a notch a sole cannot have
                if rim(ring[idx] + reading[idx, None] * outward[idx]).min() < -EDGE_MOVE_AGREE_MM:
                    continue  # a bulge beyond the notch's rim
                steps = np.arange(0.0, float(reading[idx].max()) + 1e-9, SILENT_STEP_MM)
                xy = ring[idx, None] + steps[None, :, None] * outward[idx, None]
                want = steps[None, :] <= reading[idx, None] - SILENT_SHORT_OF_EDGE_MM
                if not np.all(raised.contains(xy.reshape(-1, 2)).reshape(want.shape) | ~want):
                    continue
                fill[idx] = reading[idx]
            # Where both cameras fill, the nearer of their edges.
            nearer = (fill > 0) & ((move == 0) | (fill < move))
            by = np.where(nearer, this, by)
            move = np.where(nearer, fill, move)
    return move, by


def _rim(ring: np.ndarray, idx: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
    """The outline's course across a stretch `idx` of it, from NOTCH_RIM_POINTS points either side beyond its
    flanks (one point skipped each side): a quadratic in the frame of the chord between them. Returns, for
    points, how far each lies inside that curve (mm, + inward: counter-clockwise outline); None where the
    stretch is too long to be a notch (the rim's chord longer than NOTCH_MAX_CHORD_MM)."""
    n = len(ring)
    side = np.arange(2, 2 + NOTCH_RIM_POINTS)
    before, after = ring[(idx[0] - side) % n], ring[(idx[-1] + side) % n]
    a, b = before[0], after[0]
    chord = b - a
    length = float(np.linalg.norm(chord))
    if length < 1e-9 or length > NOTCH_MAX_CHORD_MM:
        return None
    along = chord / length
    left = np.array([-along[1], along[0]])  # inward of a counter-clockwise outline
    rim = np.vstack([before, after]) - a
    coeff = np.polyfit(rim @ along, rim @ left, 2)

    def inside(points: np.ndarray) -> np.ndarray:
        rel = points - a
        return rel @ left - np.polyval(coeff, rel @ along)

    return inside


def _whole_stretches(allowed: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """`allowed` kept only on stretches of the closed outline where every point `wanted` is allowed: a stretch is
    a run of consecutive wanted points (the outline beyond the edge both cameras show, on average)."""
    keep = allowed & wanted
    whole = np.zeros_like(keep)
    for run in closed_runs(wanted):
        whole[run] = keep[run].all()
    return whole


def depth_silent(ring: np.ndarray, outward: np.ndarray, table_points: Footprint) -> Callable[[np.ndarray], np.ndarray]:
    """Per outline point and proposed move: True where depth measured no point at the table's height between
    the outline and the proposed edge (a strip SILENT_STRIP_MM wide, up to SILENT_SHORT_OF_EDGE_MM short of it).

    That is the case the move is for: a weakly textured top edge whose last mm has no depth (the matcher
    cannot tell the top's disparity from the table's where its window straddles the step), so the depth step
    ends short of the edge both masks show. An outward error both masks share lies on the table instead (a
    contact shadow, a dark stain at the foot): the matcher measures the table's texture there at table
    height, and the point is not moved (the edge-offset check then refuses it). `table_points` are the raw
    cells with such points, not the dilated `measured_cells`, which would hide a 1 mm gap."""
    tangent = np.column_stack([-outward[:, 1], outward[:, 0]])
    across = np.arange(-0.5 * SILENT_STRIP_MM, 0.5 * SILENT_STRIP_MM + 1e-9, SILENT_STEP_MM)

    def silent(proposed: np.ndarray) -> np.ndarray:
        result = np.zeros(len(ring), bool)
        moving = np.flatnonzero(proposed > 0)
        if moving.size == 0:
            return result
        reach = np.maximum(proposed[moving] - SILENT_SHORT_OF_EDGE_MM, SILENT_STEP_MM)
        along = np.arange(0.0, float(reach.max()) + 1e-9, SILENT_STEP_MM)
        xy = (
            ring[moving, None, None]
            + along[None, :, None, None] * outward[moving, None, None]
            + across[None, None, :, None] * tangent[moving, None, None]
        )  # moving x along x across x 2
        row, col, inside = table_points.cells(xy.reshape(-1, 2))
        shape = xy.shape[:3]
        within = np.broadcast_to((along[None, :] <= reach[:, None] + 1e-9)[:, :, None], shape)
        table = table_points.mask[row, col].reshape(shape).astype(bool) | ~inside.reshape(shape)
        result[moving] = ~np.any(table & within, axis=(1, 2))
        return result

    return silent


def blob_length_mm(reconstruction: Reconstruction) -> float:
    """The longest stretch of depth beyond the edge an inward move takes for a local mismatch: BLOB_CENSUS_WINDOWS
    census windows (the sole matcher's width in pixels) at the left camera's height above the table."""
    window_px = SOLE_MATCHER_PARAMS["census_window"]
    assert isinstance(window_px, tuple)
    return BLOB_CENSUS_WINDOWS * float(window_px[0]) * mm_per_pixel(reconstruction)


def mm_per_pixel(reconstruction: Reconstruction) -> float:
    """Millimetres on the table per rectified pixel (`Reconstruction.pixel_mm`) of a stereo reconstruction."""
    pixel = reconstruction.pixel_mm
    assert pixel is not None
    return pixel


@dataclass(frozen=True)
class PlacedOutline:
    """The outline placed on the images' edge (`onto_image_edge`) and, per point, the camera whose silhouette alone
    placed it (0 left, 1 right: a notch the other camera's change mask left, `notch_fill`; -1 elsewhere)."""

    outline: np.ndarray  # closed, table mm
    one_camera: np.ndarray

    @classmethod
    def unmoved(cls, outline: np.ndarray) -> PlacedOutline:
        return cls(outline, np.full(len(outline), -1))

    def cameras_at(self, points: np.ndarray, within_mm: float = 0.5) -> np.ndarray:
        """Per point (table mm), `one_camera` of the outline point nearest it, -1 if none lies within `within_mm`."""
        if not np.any(self.one_camera >= 0):
            return np.full(len(points), -1)
        placed = np.flatnonzero(self.one_camera >= 0)
        distance = np.linalg.norm(points[:, None, :] - self.outline[None, placed, :], axis=2)
        nearest = np.argmin(distance, axis=1)
        close = distance[np.arange(len(points)), nearest] <= within_mm
        return np.where(close, self.one_camera[placed[nearest]], -1)


def onto_image_edge(reconstruction: Reconstruction, outline: np.ndarray, surface: SoleSurface) -> PlacedOutline:
    """The outline (closed, table mm) moved onto the edge both cameras show (1 mm spacing), or as it was."""
    changed_left, changed_right = reconstruction.changed_left, reconstruction.changed_right
    if not PLACE_EDGE_FROM_IMAGES or changed_left is None or changed_right is None:
        return PlacedOutline.unmoved(outline)
    if reconstruction.calibration is None or reconstruction.table_points is None:
        return PlacedOutline.unmoved(outline)  # no guard without the raw depth cells: the check judges it as it is
    ring = resample_closed(outline, 1.0)
    outward = outward_normals(ring)
    edge_height = edge_heights(surface, ring, outward)
    if not np.any(np.isfinite(edge_height)):
        return PlacedOutline.unmoved(outline)
    level = table_level(reconstruction)
    (left_pixel, left_centre), (right_pixel, right_centre) = projections(reconstruction)
    cameras = ((changed_left, left_pixel, left_centre), (changed_right, right_pixel, right_centre))
    inner, outer = stereo_offsets(ring, outward, edge_height, cameras, level)
    silent = depth_silent(ring, outward, reconstruction.table_points)
    shift = edge_shift(inner[0], inner[1], silent, outer, PLACE_EDGE_INWARD, blob_length_mm(reconstruction))
    one_camera = np.full(len(ring), -1)
    if FILL_NOTCHES and reconstruction.raised is not None:
        fill, by = notch_fill(ring, outward, inner, outer, silent, reconstruction.raised)
        filled = (shift == 0) & (fill > 0)
        shift = np.where(filled, fill, shift)
        one_camera = np.where(filled, by, -1)
    if not np.any(shift):
        return PlacedOutline.unmoved(outline)
    return PlacedOutline(ring + shift[:, None] * outward, one_camera)
