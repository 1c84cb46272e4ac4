"""Self-checks of the sole's edge itself (docs/measurements.md, Validity): the measured surface across the
outline (a rounded top edge falls away before it) and where each camera's change mask ends along the
outline's normal (a dent or bulge of 1-2 mm that the depth-step and right-image tests of
cellctl.vision.checks pass), and the outline's own shape (a notch sharper than a sole's edge bends, a spur no convex
edge makes). Each returns None or a `CheckFailure`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.errors import FailureKind
from cellctl.stereo.kernels import edge_profiles
from cellctl.vision.checks import MIN_TESTABLE, CheckFailure
from cellctl.vision.closed_path import normal_samples, run_lengths, running_median
from cellctl.vision.defaults import GLUE_OFFSET_MM
from cellctl.vision.footprint import Footprint

# The surface across the edge: sampled EDGE_OUTER_MM inside the outline and fitted as a line over
# EDGE_INNER_MM. Next to a sharp top edge the surface runs on as it does further in (the median departure round
# a sole with a sharp edge: 0.0-0.2 mm, the height noise); a top edge rounded with a few mm of radius falls
# away before the outline (0.7-0.9 mm where depth ends), and there the edge lies further out than the depth
# reaches while the glue path sits on the curve (heights and normals from a flat-top fit are wrong).
EDGE_OUTER_MM = 0.75
EDGE_INNER_MM = (3.0, 4.0, 5.0, 6.0, 7.0, 8.0)
# Medians on matrix soles (taught): sharp edges -0.06..+0.15 mm (18 soles, black ones the noisiest); rounded
# 0.38 (a 3-5 mm fillet on a grey table, whose dark curve the change mask also left out) to 0.9 mm.
EDGE_MAX_DROP_MM = 0.25
# A side wall that leans out towards the table (a draft): the surface just inside the outline rises steeply
# all the way up, so it fits the edge profile's line and passes it. The glue line GLUE_OFFSET_MM inside the
# wall's foot then lies on the wall: heights there change by 1/tan(slope) per mm of inset (2.8-7 mm per mm
# for walls 8-20 degrees off vertical), normals 70-80 degrees from vertical, outside the glue contract
# (checks.MIN_GLUE_NZ), and the part of the wall that faces away from a camera is not seen at all. Per
# outline point the measured heights at the glue line's offset and 2 mm further in give the slope; along any
# stretch of WALL_WINDOW_MM of outline, more than WALL_MAX_SHARE of the points with both heights rising steeper
# than WALL_MAX_SLOPE_DEG from horizontal is a wall, not noise. A wall whose top corner lies inside the glue
# line's offset (a thin sole) leaves the line on the top: flat there, it passes. Sharp and rounded top edges
# pass (a 3-5 mm fillet is at most ~30 degrees steep 2-4 mm in); nearer the outline, the 1 mm cells of the
# height map take in the points of a vertical wall that a camera sees, from the table up (up to 1.5 mm in on
# a black sole with a rounded edge), which is why the slope is not read there.
WALL_INNER_MM = (GLUE_OFFSET_MM, GLUE_OFFSET_MM + 2.0)
WALL_MAX_SLOPE_DEG = 60.0
WALL_WINDOW_MM = 12
WALL_MAX_SHARE = 0.6
# The outline against where each camera's change mask ends along the outline's normal. The depth-step and
# right-image tests (cellctl.vision.checks) look 1.5-7 mm either side of the outline: a local error of 1-2 mm (an edge whose
# depth dropped out, a dent, a bulge) passes them and puts the glue line 1-2 mm off its offset. Here the
# edge is located in each image's change mask (half-contrast threshold: a pixel half on the sole) along
# the normal, EDGE_SEARCH_MM either side, at the height where that camera's silhouette lies: the table
# (z = 0) where the camera sees the wall's foot, the top edge's height where the sole hides it. The
# offsets of both cameras, a median over EDGE_OFFSET_WINDOW_MM of outline, must stay within
# MAX_EDGE_OFFSET_MM (the glue tolerance is 1 mm; a sharp edge's offsets scatter by ~0.2 mm).
EDGE_SEARCH_MM = 4.0
EDGE_SEARCH_STEP_MM = 0.25
EDGE_PROFILE_MIN_KNOWN = 0.7  # of a profile's samples in the image and not excused (table-level shadow)
EDGE_PROFILE_MAX_MISFIT = 0.2  # of the known samples on the wrong side of the best step: no clear edge
EDGE_OFFSET_WINDOW_MM = 5
MAX_EDGE_OFFSET_MM = 0.8


# The outline's shape against how a sole's edge can bend. A sole's edge turns inward (concave) only at its
# waist, with a radius of tens of mm (the simulator's soles: 26 mm at the tightest over every end kind, the
# cusps' concave sides included; a last's arch is not tighter); pointed and cusped ends are convex. Taken
# as MIN_CONCAVE_RADIUS_MM, well below that (the glue line's edge is closed with a disc of this radius for
# the same reason, cellctl.vision.measurement.GLUE_EDGE_CLOSE_MM). Per outline point and chord of half-length
# h (1 mm steps up to NOTCH_MAX_HALF_CHORD_MM: windows up to 14 mm), the point may lie inside the chord by at
# most the sagitta of an arc of that radius (h^2 / 2R: 0.17 mm at h = 2, 1.1 mm at h = 5) plus
# MAX_EDGE_OFFSET_MM (the glue tolerance of 1 mm less the outline's own scatter, as for the edge offsets).
# Deeper is a notch no sole has: 2-4 mm long and 1-2 mm deep where both cameras' change masks missed the same
# edge pixels, which the depth step (fattened 5 mm), the right image (1.5 mm in, 3 mm out), the edge offsets
# (the same masks) and the 12 mm stretch rules do not see. The outline there is not the sole's edge; the glue
# line's closing bridges a narrow notch, but masks that miss the edge so are not to be trusted beside it (a
# mask fill tried in session 7 published held-out 3014 with two such notches and the glue line 1.25 mm off at
# a dent next to them). Reach: 1.2 mm deep over 2-4 mm, 1.5 mm over 2-6 mm. Long shallow dents (~1 mm over
# 6-16 mm) no shape rule separates from the outline's scatter or a waist (a 26 mm waist bends 0.9 mm over
# 14 mm): not seen.
MIN_CONCAVE_RADIUS_MM = 12.0
NOTCH_MAX_HALF_CHORD_MM = 7
# A spur out of the outline: the mirror of a notch, where a shadow or a dark strip of table beside the edge joined the
# sole's region in both cameras' masks (docs/sole-benchmark.md, forty-fourth round: 1.4 mm out over ~4 mm, which the
# notch rule, inward only, and the edge offsets, reading the same masks, do not see). A sole's edge bulges out
# sharply only at an end's tip (pointed and cusped ends: tip radius 0-5 mm), and there its flanks turn round with
# it. So per outline point and half-width h (1 mm steps up to SPUR_MAX_HALF_WIDTH_MM), the point may lie beyond
# the chord between its neighbours h either side by at most what a convex edge turning as its flanks turn could
# bulge: h sin(phi / 2), phi the turn from the incoming flank's direction (SPUR_FLANK_MM before the chord's start)
# to the outgoing one's (phi: 0 on a straight side, ~140 degrees round a pointed tip, whose tip reaches that
# bound; concave turns allow nothing), plus MAX_EDGE_OFFSET_MM as for a notch. The simulator's true outlines of
# every end kind exceed the bound by at most 0.01 mm; the outlines the cell published right by 0.2-0.7 mm (their
# scatter, bulges of 0.5-0.6 mm) and on 3 of the 170 right soles of the four matrix sets by 0.8-0.9 (narrow spurs
# of their own, 0.7-0.9 mm out over 2-3 mm, which the glue line's inset erodes away: refused, a price paid for
# safety); the spur of 62046 by 1.09 mm. Wider spurs (h > 3) are not tested: at h = 4 the scatter of right
# outlines already reaches 0.85 mm.
SPUR_MAX_HALF_WIDTH_MM = 3
SPUR_FLANK_MM = 3

# A wall too low to confirm the outline as the sole's foot. The outline is the top edge's silhouette (the camera
# on a wall's inner side sees no more); a wall leaning out towards the table puts its foot h tan(lean) beyond
# it, and the cell sees that only in depth (a ramp the edge checks read) or where the wall's lower part differs
# from the table in the images. The depth step is blurred ~1-1.5 mm either side of the edge (heights beyond a
# vertical flat sole's foot still read 30-60 % of its top 1-1.5 mm out), and the lower part of a wall lit at a
# grazing angle mostly has the table's brightness: on flat soles (6-7.5 mm) leaning 8-20 degrees the outline
# lay 0.3-1.4 mm inside the foot with every check passing (docs/sole-benchmark.md, twenty-third round). A sole
# whose wall stands LOW_WALL_MM or more somewhere (a heel) shows a lean of 8 degrees or more there as a ramp of
# 1.4 mm or more, which the edge checks refuse; lower all round, it is refused here. What stays unseen on any
# sole: a lean smaller than the cameras' view angle past the edge (a mould's draft of a few degrees), hidden
# behind the top edge from both cameras as a vertical wall is (docs/measurements.md, Wall height).
LOW_WALL_MM = 10.0
LOW_WALL_QUANTILE = 0.9  # the wall's height where it stands highest, not one stretch of it
# Where the wall's height is read: the top this far inside the outline (a coarse median of the cloud). Far enough
# in to be on the top past a leaning wall's run at the heel (a 20 mm heel leaning 20 degrees runs 7 mm: there
# the reading is 16 mm), near enough for a flat sole's top (6-7.5 mm) to be its wall's height.
WALL_HEIGHT_INSET_MM = 6.0
WALL_HEIGHT_RADIUS_MM = 3.0
LEAN_SHOWN_DEG = 20.0  # the steepest lean the refusal's words put a number on (the simulator's range: 8-20)


def chord_bulge(outline: np.ndarray, half_chord: int) -> tuple[np.ndarray, np.ndarray]:
    """Per point of a closed counter-clockwise outline: how far it lies beyond (outside) the chord between its
    neighbours `half_chord` points either side (negative: inside it), and that chord's half-length (mm)."""
    before, after = np.roll(outline, half_chord, axis=0), np.roll(outline, -half_chord, axis=0)
    chord = after - before
    length = np.linalg.norm(chord, axis=1)
    rel = outline - before
    # Left of the chord (counter-clockwise outline: towards the inside) is positive for the cross product.
    inside = (chord[:, 0] * rel[:, 1] - chord[:, 1] * rel[:, 0]) / np.maximum(length, 1e-9)
    return -inside, 0.5 * length


def concave_sag(half_chord_mm: np.ndarray) -> np.ndarray:
    """How far behind a chord of `half_chord_mm` (per point) an edge curving inward with MIN_CONCAVE_RADIUS_MM, the
    tightest a sole's edge bends, lies at its middle."""
    half = np.minimum(half_chord_mm, MIN_CONCAVE_RADIUS_MM)
    return MIN_CONCAVE_RADIUS_MM - np.sqrt(MIN_CONCAVE_RADIUS_MM**2 - half**2)


def check_outline_notch(outline: np.ndarray) -> CheckFailure | None:
    """A notch in the outline (N x 2, counter-clockwise, points 1 mm apart, closed) sharper than a sole's edge
    bends: a point lying inside the chord between its neighbours h mm either side by more than an arc of
    MIN_CONCAVE_RADIUS_MM would, plus MAX_EDGE_OFFSET_MM."""

    def notch_excess(h: int) -> np.ndarray:
        beyond, half = chord_bulge(outline, h)
        return -beyond - concave_sag(half)

    worst, at, h = _worst_excess(notch_excess, min(NOTCH_MAX_HALF_CHORD_MM, (len(outline) - 1) // 2))
    if worst > MAX_EDGE_OFFSET_MM:
        x, y = outline[at]
        chord_mm = float(np.linalg.norm(outline[(at + h) % len(outline)] - outline[at - h]))
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the outline has a notch at outline point {at} ({x:.1f}, {y:.1f}) mm: {worst:.1f} mm deeper than a "
            f"sole's edge can curve inward over a {chord_mm:.0f} mm chord (a radius of {MIN_CONCAVE_RADIUS_MM:g} mm "
            f"at the tightest; limit {MAX_EDGE_OFFSET_MM:g} mm): the outline there is not the "
            "sole's edge",
        )
    return None


def check_outline_spur(outline: np.ndarray) -> CheckFailure | None:
    """A spur out of the outline (N x 2, counter-clockwise, points 1 mm apart, closed) that no convex edge between
    its flanks could make: a point lying beyond the chord between its neighbours h mm either side by more than
    h sin(phi / 2), phi the turn between the flanks beyond them, plus MAX_EDGE_OFFSET_MM."""

    def spur_excess(h: int) -> np.ndarray:
        beyond, _ = chord_bulge(outline, h)
        return beyond - h * np.sin(0.5 * np.clip(_flank_turn(outline, h, SPUR_FLANK_MM), 0.0, np.pi))

    worst, at, h = _worst_excess(spur_excess, min(SPUR_MAX_HALF_WIDTH_MM, (len(outline) - 1) // 2 - SPUR_FLANK_MM))
    width_mm = 2 * h
    if worst > MAX_EDGE_OFFSET_MM:
        x, y = outline[at]
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the outline has a spur at outline point {at} ({x:.1f}, {y:.1f}) mm: {worst:.1f} mm further out over "
            f"{width_mm} mm than a sole's edge turning as the outline turns either side of it can bulge (limit "
            f"{MAX_EDGE_OFFSET_MM:g} mm): the outline there is not the sole's edge (something beside it was taken "
            "for the sole, most often a shadow: light the table so that no shadow falls beside the sole)",
        )
    return None


def _worst_excess(excess_at: Callable[[int], np.ndarray], most: int) -> tuple[float, int, int]:
    """The largest of `excess_at(h)` (per outline point) over h = 1..most, with its point and h; (0, 0, 0) where none
    exceeds 0."""
    worst, at, half = 0.0, 0, 0
    for h in range(1, most + 1):
        excess = excess_at(h)
        k = int(np.argmax(excess))
        if excess[k] > worst:
            worst, at, half = float(excess[k]), k, h
    return worst, at, half


def _flank_turn(outline: np.ndarray, half: int, flank: int) -> np.ndarray:
    """Per point: the signed turn (radians, counter-clockwise positive: convex on a counter-clockwise outline) from
    the direction of the `flank` points before its neighbour `half` points back to that of the `flank` points
    after its neighbour `half` points on."""
    incoming = np.roll(outline, half, axis=0) - np.roll(outline, half + flank, axis=0)
    outgoing = np.roll(outline, -(half + flank), axis=0) - np.roll(outline, -half, axis=0)
    cross = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
    return np.arctan2(cross, np.sum(incoming * outgoing, axis=1))


def check_wall_height(edge_height: np.ndarray) -> CheckFailure | None:
    """Refuse a sole whose wall is lower than LOW_WALL_MM all round (the LOW_WALL_QUANTILE of `edge_height`, the
    measured top WALL_HEIGHT_INSET_MM inside each outline point): too low for depth to show whether it leans
    out, so its outline cannot be confirmed as its foot (the constants' comment says why)."""
    known = edge_height[np.isfinite(edge_height)]
    if not len(known):
        return None  # no surface near the edge: the surface checks refuse it
    high = float(np.quantile(known, LOW_WALL_QUANTILE))
    if high >= LOW_WALL_MM:
        return None
    reach = high * np.tan(np.radians(LEAN_SHOWN_DEG))
    return CheckFailure(
        FailureKind.WALL_TOO_LOW,
        f"the sole's wall stands at most {high:.1f} mm high ({100 * LOW_WALL_QUANTILE:.0f}th percentile round the "
        f"outline; the cell needs {LOW_WALL_MM:.0f} mm somewhere): on a wall this low, depth cannot tell a vertical "
        f"wall from one leaning out, whose foot would lie up to {reach:.1f} mm (at {LEAN_SHOWN_DEG:.0f} degrees) "
        "beyond the outline, so the outline cannot be confirmed as the sole's edge",
    )


def check_edge_profile(
    outline: np.ndarray,
    outward: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    detail: Callable[[], str] | None = None,
) -> CheckFailure | None:
    """The surface across the edge: does the top run on flat to the outline, or fall away before it?

    `surface_height(xy N x 2) -> N` is the measured height (NaN where none). Per outline point the height
    EDGE_OUTER_MM inside is compared with the line through the heights further in; the median over the
    outline (a rounded edge runs round the sole, a single bad patch does not move the median) must not fall
    more than EDGE_MAX_DROP_MM below it. detail: words added to a refusal (cellctl.vision.rounded_edge.detail:
    the edge and the curve in numbers), asked for only then.
    """
    fall = top_falls(outline, outward, surface_height, (EDGE_OUTER_MM,))[:, 0]
    usable = np.isfinite(fall)
    if np.count_nonzero(usable) < MIN_TESTABLE * len(outline):
        return None  # too little surface measured near the edge: the other checks and the glue path speak
    drop = float(np.median(fall[usable]))
    if drop > EDGE_MAX_DROP_MM:
        more = detail() if detail is not None else ""
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the sole's top falls {drop:.1f} mm (median round the outline) below the line of its top "
            f"{EDGE_INNER_MM[0]:g}-{EDGE_INNER_MM[-1]:g} mm in over the last few mm before its outline: its top edge "
            "is rounded or bevelled, so the edge lies beyond where its depth was measured, or its top curves there "
            "(a raised lip levelling off), and the glue path near it is on a curve, not a flat top"
            + (f" ({more})" if more else ""),
        )
    return None


def top_falls(
    outline: np.ndarray,
    outward: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    at: tuple[float, ...],
) -> np.ndarray:
    """Per outline point (N) and distance in `at` (K): how far the measured top lies below the line through its
    heights further in (EDGE_INNER_MM, 3-8 mm: the top before any rounding), N x K, NaN where unknown. On a
    sharp edge ~0 (the height noise); on a rounded one it grows towards the outline."""
    inner = np.array(EDGE_INNER_MM)
    heights = np.column_stack([surface_height(outline - d * outward) for d in inner])
    weight = np.isfinite(heights).astype(np.float64)
    z = np.nan_to_num(heights)
    # Per-row least-squares line z = a + b d over the finite samples (sums of products).
    s0, s1, s2 = weight.sum(1), (weight * inner).sum(1), (weight * inner**2).sum(1)
    t0, t1 = (weight * z).sum(1), (weight * z * inner).sum(1)
    det = s0 * s2 - s1 * s1
    fitted = (s0 >= 4) & (np.abs(det) > 1e-9)
    b = (s0 * t1 - s1 * t0) / np.where(fitted, det, 1.0)
    a = (t0 - b * s1) / np.maximum(s0, 1.0)
    near = np.column_stack([surface_height(outline - d * outward) for d in at])
    line = a[:, None] + b[:, None] * np.array(at)[None, :]
    return np.where(fitted[:, None], line - near, np.nan)


def check_steep_wall(
    outline: np.ndarray, outward: np.ndarray, surface_height: Callable[[np.ndarray], np.ndarray]
) -> CheckFailure | None:
    """A stretch of the outline (points 1 mm apart, closed) where the measured surface just inside rises like
    a wall (steeper than WALL_MAX_SLOPE_DEG): the glue line there would lie on the wall, whose heights and
    normals the cameras above cannot give within tolerance."""
    near, far = (surface_height(outline - d * outward) for d in WALL_INNER_MM)
    known = np.isfinite(near) & np.isfinite(far)
    slope = np.where(known, far - near, 0.0) / (WALL_INNER_MM[1] - WALL_INNER_MM[0])
    steep = known & (slope > np.tan(np.radians(WALL_MAX_SLOPE_DEG)))
    window = np.ones(WALL_WINDOW_MM)
    wrap = WALL_WINDOW_MM - 1
    count = np.convolve(np.concatenate([known, known[:wrap]]).astype(float), window, "valid")
    hits = np.convolve(np.concatenate([steep, steep[:wrap]]).astype(float), window, "valid")
    share = np.where(count >= WALL_WINDOW_MM / 2, hits / np.maximum(count, 1.0), 0.0)
    worst = int(np.argmax(share))
    if share[worst] > WALL_MAX_SHARE:
        return CheckFailure(
            FailureKind.SURFACE_NOT_MEASURED,
            f"the sole's surface rises like a wall just inside its outline (more than {WALL_MAX_SLOPE_DEG:g} degrees "
            f"steep between {WALL_INNER_MM[0]:g} and {WALL_INNER_MM[1]:g} mm in, {100 * share[worst]:.0f} % of a "
            f"{WALL_WINDOW_MM} mm stretch from outline point {worst}): a side wall leaning out to its foot, on which "
            "the glue line would lie; its heights and normals cannot be measured within tolerance from above",
        )
    return None


def edge_offset_pair(
    outline: np.ndarray,
    outward: np.ndarray,
    level: np.ndarray,
    changed: np.ndarray,
    table_to_pixel: Callable[[np.ndarray], np.ndarray],
    table_level: Footprint | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per outline point: where the camera's changed region ends along the outward normal, in mm from the
    outline (+: beyond it), NaN where the profile shows no clear single edge.

    Two readings from one sampling, (innermost, outermost): where several steps fit equally well (samples
    between them unknown: out of the image, or changed on `table_level` cells), the innermost of them, and the
    one farthest out; unknown samples to the end of the search give no edge. The check reads both (check_edge_offsets on each): missing evidence must not be
    read in the outline's favour. Stereo drags a textured table's depth 1-2 mm onto the edge of a weakly
    textured (black) sole, so the sole's own edge band is on `table_level` cells, and the innermost step put
    the edge on an outline that stopped short with the depth (1.4 mm inside the true edge over 65 mm, glue
    line 1.4 mm off, on a held-out matrix sole).
    """
    steps = np.arange(-EDGE_SEARCH_MM, EDGE_SEARCH_MM + 1e-9, EDGE_SEARCH_STEP_MM)
    n, k = len(outline), len(steps)
    points = normal_samples(outline, outward, steps, level)
    xy = points[:, :, :2]
    px = np.round(table_to_pixel(points.reshape(-1, 3))).astype(np.int64).reshape(n, k, 2)
    # A changed pixel on the measured table outside (steps > 0) is a shadow, no evidence: the cells are looked up
    # here, the pixels' state in the kernel.
    on_table = None if table_level is None else table_level.contains(xy.reshape(-1, 2)).reshape(n, k)
    # The misfit of a step between samples j-1 and j, j = 0..k (unchanged before it plus changed from it on), its
    # innermost and outermost least position and the known samples per profile, in C (cellctl.stereo.kernels:
    # one pass where numpy took ~20 over the n x k samples; the same integers, np.argmin's first of ties and
    # the last by the reversed argmin).
    first_out = int(np.searchsorted(steps, 0.0, side="right"))  # the first sample beyond the outline
    innermost, outermost, misfit, count = edge_profiles(px, changed, on_table, first_out)
    enough = count >= EDGE_PROFILE_MIN_KNOWN * k
    clear = enough & (misfit <= EDGE_PROFILE_MAX_MISFIT * np.maximum(count, 1))
    readings = []
    for best in (innermost, outermost):
        offset = steps[0] - 0.5 * EDGE_SEARCH_STEP_MM + best * EDGE_SEARCH_STEP_MM
        # A step at either end of the search is no edge found within it.
        readings.append(np.where(clear & (best > 0) & (best < k), offset, np.nan))
    return readings[0], readings[1]


def mean_of_known(readings: np.ndarray) -> np.ndarray:
    """Per column of `readings` (cameras x outline points) the mean of the known (finite) ones, NaN where none."""
    known = np.isfinite(readings)
    return np.where(known.any(axis=0), np.nansum(readings, axis=0) / np.maximum(known.sum(axis=0), 1), np.nan)


def offset_median(offsets: np.ndarray) -> np.ndarray:
    """Per point of a closed outline (points 1 mm apart) the median of `offsets` over EDGE_OFFSET_WINDOW_MM
    centred on it, NaN where no more than half of the window is known."""
    half = EDGE_OFFSET_WINDOW_MM // 2
    return running_median(offsets, half, quorum=half + 1)


# The running median over EDGE_OFFSET_WINDOW_MM (5 points) is for one point's scatter; it reads a bump of the outline
# beyond the edge at its flanks' value while the glue line, eroded from the outline, follows its peak. Where every
# camera reads the edge more than MAX_EDGE_OFFSET_MM inside the outline at AGREED_RUN_POINTS consecutive points (1 mm
# apart), the nearer-the-outline of their readings there is the offset: two cameras' masks agreeing on neighbouring
# points is no single point's scatter. Found on smeared stretches first (std20 sole 1 taught: the outline 0.8-1.15
# mm beyond a black sole's edge over 9 mm, both cameras reading -0.6 there and -0.9 on the peak's two points,
# median 0.6: glue path valid and 1.02 mm off). Until session 20 shorter bumps were left to the median (a 2-3 mm bump
# of 0.9 mm put the glue line 0.6-0.7 mm off on set-2000 soles 2015 and 2073); on soles never looked at before they
# came within a few hundredths of the tolerance: fresh sole 9327, a 3 mm bump on a square heel's side that both
# cameras read 0.9-1.4 mm inside, its glue point 0.98 mm off; 9315, 1.4 mm at the toe, its length 0.97 mm long
# (docs/sole-benchmark.md, twentieth round). Now the agreed readings count anywhere on the outline.
AGREED_RUN_POINTS = 2
# A reading more than MAX_EDGE_OFFSET_MM inside (the cameras' mean, or their agreed one) is the outline's error only as
# far as the shape of a sole's edge allows. Where the outline runs smoothly past a stretch of such readings and the
# cameras read it on the sole's edge either side, the true edge can lie no further inside it than the chord through
# those sides' edges, less the outline's own bulge over that chord, and less what an edge curving inward with
# MIN_CONCAVE_RADIUS_MM (the tightest a sole's edge bends, as for check_outline_notch) sags behind the chord. Deeper,
# the masks have a notch the sole has not: a patch of the table's colour meeting a white sole's edge (fresh sole 46059:
# both cameras 2.4-3.6 mm inside over 2 points, the outline 0.36 mm from the true edge there) or a speck of a black
# sole's edge left unchanged (46073: 1.9-2.9 mm over 2-3 points, the outline 0.1 mm off). Every chord of 1 to
# NOTCH_MAX_HALF_CHORD_MM points either side whose ends the cameras read on the outline (within CHORD_END_MM, half the
# limit: the readings' own scatter and step) bounds the true edge, so the tightest of those bounds holds. A real bump of
# the outline bulges over such chords (the bound keeps its reading; over chords lying on the bump itself its flanks read
# inside, fresh sole 39015: 0.4-0.6 mm on a 5 mm bump 0.8-1.06 mm beyond the edge, and give no bound), a smeared stretch
# reads inside at the chords' ends (std20 sole 1: 0.6 mm over 9 mm, 0.9 on its peak's two points), a long offset has no
# ends beyond it, and a wide shallow concavity the outline bridged is allowed its sag: their readings stand. A chord's
# ends read beyond the outline do not lift the bound (no reading beyond counts in the outline's favour).
CHORD_END_MM = 0.5 * MAX_EDGE_OFFSET_MM


def agreed_offsets(offsets: list[np.ndarray], outline: np.ndarray | None = None) -> np.ndarray:
    """Per outline point (closed, 1 mm apart): where two or more cameras all read the edge inside the outline, the
    reading nearest the outline, kept only inside runs of AGREED_RUN_POINTS or more points whose such reading lies
    more than MAX_EDGE_OFFSET_MM inside; 0 elsewhere (one camera alone is left to the running median). With the
    `outline` (N x 2, counter-clockwise), each reading counts only as deep as the outline's course past the run
    predicts (`held_to_course`)."""
    readings = np.vstack(offsets)
    if len(readings) < 2:
        return np.zeros(readings.shape[1])
    known = np.all(np.isfinite(readings), axis=0)
    filled = np.where(known[None, :], readings, 0.0)
    nearest = np.where(known, np.max(filled, axis=0), 0.0)  # the least far inside; >= 0 if one is not
    if outline is not None:
        nearest = np.where(known, held_to_course(np.where(known, nearest, np.nan), outline), 0.0)
    run = run_lengths(nearest < -MAX_EDGE_OFFSET_MM) >= AGREED_RUN_POINTS
    return np.where(run, nearest, 0.0)


def held_to_course(readings: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """`readings` (per point of the closed counter-clockwise `outline`, 1 mm apart; NaN: unknown) with each reading
    more than MAX_EDGE_OFFSET_MM inside held to the deepest the shape of a sole's edge allows there (the comment
    above): per chord of 1 to NOTCH_MAX_HALF_CHORD_MM points either side whose ends are both read within CHORD_END_MM,
    their mean reading (at most 0) less the outline's bulge over the chord and a MIN_CONCAVE_RADIUS_MM arc's sag; the
    tightest of them, at most 0. Where no chord qualifies the reading stands."""
    deep = np.nan_to_num(readings) < -MAX_EDGE_OFFSET_MM
    if not np.any(deep):
        return readings
    near = np.abs(np.nan_to_num(readings, nan=np.inf)) <= CHORD_END_MM
    index = np.arange(len(outline))
    bound = np.full(len(outline), -np.inf)
    for half in range(1, min(NOTCH_MAX_HALF_CHORD_MM, (len(outline) - 1) // 2) + 1):
        before, after = np.roll(index, half), np.roll(index, -half)
        usable = near[before] & near[after]
        ends = np.minimum(0.5 * (readings[before] + readings[after]), 0.0)
        beyond, half_mm = chord_bulge(outline, half)
        bound = np.where(usable, np.maximum(bound, ends - beyond - concave_sag(half_mm)), bound)
    return np.where(deep, np.maximum(readings, np.minimum(bound, 0.0)), readings)


def check_edge_offsets(offsets: list[np.ndarray], outline: np.ndarray | None = None) -> CheckFailure | None:
    """The outline (points 1 mm apart, closed) against the edges the cameras' change masks show there.

    `offsets`: per camera, one of `edge_offset_pair`'s readings along the outline. Their mean per point, a running median over
    EDGE_OFFSET_WINDOW_MM, must stay within MAX_EDGE_OFFSET_MM of the outline everywhere it is known, and so must
    the cameras' agreed readings (`agreed_offsets`, held to the `outline`'s course where it is given: N x 2,
    counter-clockwise).
    """
    mean = mean_of_known(np.vstack(offsets))
    if outline is not None:
        mean = held_to_course(mean, outline)
    if np.count_nonzero(np.isfinite(mean)) < MIN_TESTABLE * len(mean):
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the sole's edge is not clear in the images: only {np.count_nonzero(np.isfinite(mean))} of "
            f"{len(mean)} outline points show one within {EDGE_SEARCH_MM:g} mm",
        )
    local = np.nan_to_num(offset_median(mean), nan=0.0)  # too little known: no evidence against the outline
    agreed = agreed_offsets(offsets, outline)
    local = np.where(np.abs(agreed) > np.abs(local), agreed, local)
    worst = int(np.argmax(np.abs(local)))
    if abs(local[worst]) > MAX_EDGE_OFFSET_MM:
        where = "beyond" if local[worst] > 0 else "inside"
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the sole's edge in the images lies {abs(local[worst]):.1f} mm {where} the outline at outline point "
            f"{worst} (limit {MAX_EDGE_OFFSET_MM:g} mm): the outline there is not the sole's edge",
        )
    return None
