"""Self-checks a measurement must pass before it is valid (docs/measurements.md, Validity).

A refused cycle is an inconvenience; a wrong number published as valid drives the robot's nozzle into the
fixture. Each check compares a result with evidence it was not derived from:

- outline against the depth step: just inside the outline the sole must rise above the table, a little
  further out than stereo edge fattening reaches it must not (a rim cut off by the edge finder, a
  shadow or a neighbouring object taken for sole);
- outline against the right camera (taught table only): the outline, found in the left image, placed in
  the right image must have changed pixels just inside and the taught table just outside;
- glue path: heights continuous along the path and within the sole's own height range, normals
  consistent with the surface fitted around each point.

The checks of the edge itself (the surface across it, where each camera's change mask ends along the
outline's normal) are in cellctl.vision.edge_checks.

Each returns None or a `CheckFailure` (kind and reason); cellctl.vision.measurement refuses on the first.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.closed_path import closed_runs, outward_normals, running_median
from cellctl.vision.defaults import AVERAGED_FRAMES, GLUE_HEIGHT_TOLERANCE_MM, MORE_EXPOSURES
from cellctl.vision.footprint import Footprint

OUTLINE_INSIDE_MM = 2.0  # the sole must rise above the table this far inside its outline...
OUTLINE_OUTSIDE_MM = 7.0  # ...and not this far outside (stereo edge fattening reaches ~5 mm)
# Without a taught table nothing but depth checks the colour test's edge, and a sole the colour test cuts short
# (a dark rim read as table; a wall leaning out, shaded unlike the top) rises a rim's or wall's width (4-9 mm)
# beyond it all round: on the matrix set 2000, untaught, 10 of 20 valid-but-wrong results, 5-9.5 mm short.
# Edge fattening reaches past 3 mm only along stretches (std soles 5 and 10: 67-70 % of a 12 mm stretch), so
# the whole outline's share is tested at this distance (`check_outline_depth`, supplementary); the local test
# keeps OUTLINE_OUTSIDE_MM. In pixels, as fattening is (the matcher's windows): 3.1 mm at the default rig's
# 0.39 mm per pixel, 6.2 mm through the half-size test rig.
UNTAUGHT_OUTSIDE_PX = 8.0
MIN_OUTLINE_AGREEMENT = 0.9  # of the testable outline points
# Raised specks apart from the sole (a mismatch at the far side of an occlusion band, heavy sensor noise: up to
# ~27 mm2 on the matrix's noisiest soles) are no evidence: one 7 mm outside a plain sole's heel refused an outline
# within 0.53 mm of the truth (set 33000). A part of the sole the outline missed joins the sole's raised region
# across the outline, or (a thin tip whose depth broke off) lies near it: it stays evidence.
RAISED_SPECK_MM2 = 50.0
RAISED_SPECK_GAP_MM = 3.0
MIN_TESTABLE = 0.5  # of the outline points: fewer with evidence and the outline cannot be confirmed
# Locally: in any stretch of this many outline points (1 mm apart), at most this share may disagree.
LOCAL_WINDOW_MM = 12
MAX_LOCAL_DISAGREEMENT = 0.6
# Against the right image also: no run of this many consecutive disagreeing points (1 mm apart). A spur of the
# outline 1.5-2 mm beyond the edge over 3-4 mm (specks of a shadow band the left mask kept beside a ring-lit sole,
# 62047: a glue point 1.43 mm off) is a third of a stretch; on the 4 x 84 matrix soles and the other-lights set
# measured right the longest run was 2 (docs/sole-benchmark.md, forty-second round).
MAX_DISAGREEING_RUN = 2
RIGHT_INSIDE_MM = 1.5
RIGHT_OUTSIDE_MM = 3.0
# Past the top edge of a wall facing away from the camera, at the edge's height: unchanged if the outline is
# on the edge. The projection's error from the edge height (~2 mm at a ~10 degree view) is ~0.4 mm.
RIGHT_EDGE_OUT_MM = 0.75
# The table RIGHT_OUTSIDE_MM out counts as seen only if the table this much nearer is seen too: a ray that just
# grazes a tall wall's top edge lands within a pixel or two of it in the image, where the change mask's blurred
# boundary (or a contact shadow at the wall's foot) marks the table changed (set 33000: a white sole's 22 mm
# waist, 12 mm of an outline within 0.69 mm of the truth refused for it).
RIGHT_CLEAR_MM = 1.0
CLAIMED_CELL_MM = 0.5  # raster of the outline's interior for the right camera's view past the edge
HIDDEN_STEP_MM = 1.0  # the ray to the camera is followed in these steps of height...
HIDDEN_MAX_MM = 60.0  # ...up to the tallest sole
GLUE_HEIGHT_MARGIN_MM = 1.5  # glue heights beyond the sole's own height range by more than this: not on it
# Height change per mm along the path between neighbouring glue points. A sole's top under the glue path rises at
# most ~0.5 (a short sole's toe spring: 0.52 on a 167 mm simulated sole) and the fitted heights' steps scatter by up
# to ~0.4 mm over 2 mm on black rubber; a top steeper than 45 degrees along the path is no gluing surface (the
# normals' own bound, MIN_GLUE_NZ, is 60 degrees), so a steeper step is a jump of the fit, not of the sole.
GLUE_MAX_SLOPE = 1.0
# Smoothed path against its own raw samples (after lone outliers are repaired): a patch's height noise on a
# black sole reaches ~1.4 mm at worst; a failed fit is off by tens of mm.
GLUE_MAX_DEVIATION_MM = 2.5
# That noise is the default rig's (1280 x 1024, 60 mm baseline, 550 mm up): a disparity pixel spans 3.56-3.6 mm of
# depth at the table (its tilts and placements), at most this. A patch's height noise grows with that span, so on a
# coarser rig the limit grows with it (`glue_deviation_limit`; the distorted rig: 4.8 mm, limit 3.3): the
# half-size test rig spans 7.1 mm, limit 4.9, and its patches read up to 2.7 mm off the smoothed path where nothing
# failed (the station's replayed cycle, seed 1: refused at 2.5 on one machine, not on another); a failed fit is
# still off by tens of mm.
GLUE_DEVIATION_DEPTH_PX_MM = 3.6
# Path normal against the patches' own normals smoothed along the path: these are noisy (up to ~20-28 degrees
# on plain black soles), so the check catches gross faults only; the path normal itself is far better. A point
# beyond it is refused only if it is that far from the depth's own plane there too (glue_path.depth_normals, up to
# ~18 degrees from right glue normals): a colour edge on the sole tilts the image patches' fits (a rim: 55 degrees
# on a glue normal 2.2 degrees from the truth), and the noise tail of both, one from the images' fits and one from
# the matcher's depth, met the limit at the same point on none of the matrix's soles.
GLUE_MAX_NORMAL_DEG = 30.0
# The glue normals take the slope across the path over 15 mm (glue_path.GLUE_NORMAL_BASE_MM: a sole's top is far
# flatter over that than the 5 degree tolerance). A top that curves within a few mm of its edge is not: a cupsole's
# lip rising 1.5-4 mm over its last 5-12 mm leans 10-35 degrees at the glue line, and five of sixteen such soles were
# published with glue normals 20-27 degrees off (`lipped-edge`, set 47000); lips of 0.65-1.4 mm, six of nine
# published 6-9 degrees off (docs/sole-benchmark.md, thirty-fifth round). The glue points' own local estimates see
# it: per point, the slope across the path (towards the outline) of the image patches' normals (4 mm fits: they
# follow a lip within ~0.03 in the median) and of the depth's own plane (6 mm: it averages a lip's curve, from a fifth
# to two thirds of the patches' reading), less the glue normal's. Over the 174 glue paths of the fresh sets 39000,
# 40000, 43000 and 46000 (every sole that reached its glue path, those the precision check refuses included; the
# glue normals' slope across within 0.046 of the truth's on every 80 mm stretch) the patches' median along the whole
# path stayed within 0.043 (the depth's 0.041), and the running median over 80 mm of both, where they lean the same
# way (the smaller), within 0.127 but once: 0.20 along a black sole's square heel (40004), where both estimates were
# biased at an edge across the cameras' baseline and the glue normals were right; no path's patches read beyond 0.06
# where the depth's leaned the same way. The lipped soles published wrong: 0.068-0.46 along the path (their depth's
# 0.022-0.27, the same way; a black sole's narrow lip, 1.8 mm over 6.5, 0.19 and 0.037), 0.35-0.41 on a stretch
# for the steep lips. A lip that leans at the glue line by less than the limit all round (3.4 degrees) can still leave its
# worst glue normal beyond 5 degrees: the noise's tail comes on top (docs/measurements.md, Validity).
GLUE_TILT_STRETCH_MM = 80.0
GLUE_MAX_TILT_PATH = 0.06  # 3.4 degrees, 1.4 times the largest of the right paths
GLUE_MAX_TILT_STRETCH = 0.3  # 17 degrees, 1.5 times the largest of the right paths
# The same lip round part of the sole only (a heel cup) leans less than GLUE_MAX_TILT_STRETCH at the glue line where
# its normals are already 8-21 degrees off (`heel-cup`, 12 soles from 47400: four published WRONG). Its height shows
# more clearly than its lean: the glue line's patch heights stand above the line through the top's heights 6 and 15
# mm further in by most of the lip's height (glue_path.edge_rise). Over 80 mm of path (the running median) that rise
# read at most 0.84 mm on the 174 glue paths of the four fresh sets (a black sole's rim, whose colour edge pulls the
# patches; the next 0.80, 0.72) and 1.21-2.42 mm on every heel cup, the four published wrong among them (1.21-1.79).
GLUE_MAX_RISE_MM = 1.0
MIN_GLUE_NZ = 0.5  # a glue normal more than 60 degrees off vertical is not on a sole's top surface
# A glue point is measured if the cloud has MIN_CLOUD_POINTS (12, ~4 per mm^2) within GLUE_COVER_RADIUS_MM of
# it. A patch fit (4 mm) bridges small holes, but a path that runs over unmeasured or thinly measured surface
# for more than a few per cent of its points (0-2 % on soles with sharp edges seen at 0.39 mm per pixel;
# 10-50 % over a steep bevelled wall the stereo cannot see, or through a wide-angle rig's coarser pixels)
# gets its heights from elsewhere: 1-8 mm off on simulated soles.
GLUE_COVER_RADIUS_MM = 1.0
MAX_GLUE_UNCOVERED = 0.05
# The heel and toe heights' patches: every valid result of the matrix sets 16000 and 18000 held 1.0-1.1 times the
# points a patch's area over a pixel's footprint gives (the top lies nearer the cameras than the table); a glossy
# sole published 2.6 mm low at its heel held 0.11 (fresh set 19000, sole 19020; docs/sole-benchmark.md,
# twenty-fourth round).
MIN_HEIGHT_SUPPORT = 0.5
# The glue heights' precision: the median along the path of each height's expected error (the sd of the fit that
# gave it: glue_path.sample_variance's noise model and the fit's bias, cellctl.vision.surface.path_heights), as a
# share of the glue-height tolerance. The matrix's valid soles read 0.11-0.55 mm (black rubber ~0.27 in the median);
# black soles with half the simulator's texture contrast read 0.47-0.61 and white soles through a rig of half the
# resolution 0.57-0.64, and both were published 1.0-1.8 mm off before this check (session 12).
# Where the check bites (black soles, 1 DN of sensor noise) a path's worst point is the tail of its noise: the same
# scene shot again with new noise moves it elsewhere (matrix sole 9029: +1.08 mm on one shot, 0.51-0.84 on five
# others; /work/notes/s19/probe2.py). Its multiple of the median scatters round 2.2 whatever the median (82 black
# valid results with the check off: the four matrix sets, both standard 20s and the fresh set 9000-9041; a lognormal
# of median 2.19 and log-sd 0.22, max seen 3.65), so a limit on the median sets how often a published path has a
# point beyond the tolerance. The share is set for about one such result in 800 valid ones (~1 % at the limit
# itself): 0.28 x 3.65 = 1.02. At 0.40 (sessions 17-18, set for nine soles in ten *at* the limit) the model expects
# 1.3 among those 251 results and one was published (9029, 1.08 mm); 0.28 refuses 28 of them, all black.
# (docs/sole-benchmark.md, nineteenth round.)
GLUE_TYPICAL_SD_SHARE = 0.28
# On the mean of a cycle's four exposures (cellctl.cameras.averaging) the expected error falls with the sensor's noise
# (black soles 0.11-0.22 mm in the median, against 0.25-0.46 on one exposure), but part of the worst point's error is
# the scene's own (where image fits fail, the cloud's plane that replaces them) and does not average: the
# same bump sits in every exposure (fresh sole 29073, black: 0.91-0.97 mm on each of four exposures, each refused at
# 0.30-0.32; 1.01 mm on their mean, published at 0.19). So the multiple is larger on the mean: over 127 black and grey
# valid results on the mean (four matrix sets and the fresh set 29000) its median is 2.7 (2.2 on one exposure),
# log-sd 0.25, at most 5.23 on a black sole (29073) and 6.4 on a grey one whose expected error is a third of the
# limit (0.09 mm: 0.57 mm worst). Taken as on one exposure, the worst multiple seen: 1 / 5.23 = 0.19 of the
# tolerance (docs/sole-benchmark.md, twenty-eighth round). Calibrated at four exposures; more lower the noise further
# and raise the multiple again: GLUE_SD_SHARE_PER_DOUBLING below.
# Only for a clean camera's mean: a noisy camera measured wholly on the mean (`Reconstruction.from_mean`) has a mean
# about as noisy as one clean exposure, where GLUE_TYPICAL_SD_SHARE holds (its multiples 2.5 on heavy noise; 57
# valid results on the heavy- and moderate-noise sets at that share, none wrong, worst glue height 0.70 mm).
GLUE_TYPICAL_SD_SHARE_AVERAGED = 0.19
# On a mean of more than the cycle's four exposures the multiple grows, as said: measured on eight (the four fresh
# sets 39000-46000, the median limit off; docs/sole-benchmark.md, fortieth round) its median is 3.19 against 2.86 on
# four (log-sd 0.28 and 0.26; black soles at most 6.67 against 5.92), while the black soles' median expected error
# falls from 0.175 to 0.145 mm. So the share shrinks by their ratio per doubling of the exposures beyond four (0.170
# on eight: 163 of the 169 results published, none wrong, against 156 of 165 on four at 0.19; beyond eight not
# measured, the same factor per doubling taken: 0.152 on sixteen). Fewer than four leave more noise and a smaller
# multiple: 0.19 holds there with room.
GLUE_SD_SHARE_PER_DOUBLING = 2.86 / 3.19
# Each glue point's own expected error, besides the median's: at most this share of the tolerance. Half the
# tolerance is one where an error of two expected errors (one point in twenty where the model holds) is already out
# of it: no height there is a measurement within the tolerance, whatever the rest of the path. Over the 131 results
# valid on the matrix sets 19000 and 32000 and the soft-focus, dim-exposure and defocus probes no point read more
# than 0.50 mm, and the points over 0.3 mm were 1.6 expected errors off at most (the noise model is conservative
# where narrow fits round a pointed end raise it). One result read more: a black sole through a lens slightly
# softer than the simulator's (sweep sole 50010, defocus 0.4 px), its path's median 0.18 mm but a 24 mm stretch
# at 0.43-0.61 mm, published 1.15 mm off there (docs/sole-benchmark.md, twenty-ninth round).
GLUE_POINT_SD_SHARE = 0.5
# That calibration covers rigs that look at the table within CALIBRATED_OBLIQUENESS_DEG of its normal
# (TablePlane.obliqueness_deg): the simulator's rigs (2.5-3.3 degrees) and probes of the standard soles 7000-7015 on
# rigs tilted to 5.0 and 6.8 degrees (black soles' multiples up to 2.78). On probes at 9.7 and 12.2 degrees 3 of 15
# black soles were published with glue heights 1.00-1.18 mm off at medians of 0.28-0.34 mm (multiples 3.0-4.25;
# docs/sole-benchmark.md, seventeenth round). With that little evidence the limit there takes the worst multiple
# seen: 1 / 4.25 = 0.235 of the tolerance, a factor OBLIQUE_SD_SHARE_FACTOR of the calibrated share.
CALIBRATED_OBLIQUENESS_DEG = 7.0
OBLIQUE_SD_SHARE_FACTOR = 0.84


@dataclass(frozen=True)
class CheckFailure:
    kind: FailureKind
    reason: str
    # Set where the same scene on the mean of this many exposures in all may pass (check_glue_precision): a
    # cycle may grab the further ones and measure once more (cellctl.service.measuring).
    more_exposures: int | None = None


def check_outline_depth(
    outline: np.ndarray,
    outward: np.ndarray,
    raised: Footprint,
    measured: Footprint,
    footprint: Footprint | None = None,
    hidden: np.ndarray | None = None,
    outside_mm: float = OUTLINE_OUTSIDE_MM,
    supplementary: bool = False,
) -> CheckFailure | None:
    """The outline (N x 2, table mm) against the depth step (cells where most points rise above the table):
    raised OUTLINE_INSIDE_MM inside it, not `outside_mm` outside, over the whole outline and along every stretch
    of it. A `supplementary` test (UNTAUGHT_OUTSIDE_PX, untaught, after the main one) reads the whole outline only, and
    too few points with depth on both sides (near a tall sole's wall the table 3 mm out is often occluded) is
    no evidence against the outline there: the main test has already asked for enough.

    With the `footprint` the outline bounds, points whose test positions fall on the wrong side of it (past
    a pointed tip, across a narrow waist) are not tested: there the offset along the normal means nothing.
    `hidden`: outline points whose outside test position the camera cannot see (behind a tall sole's wall
    facing away): no depth is expected there, so they neither count for nor against the outline.

    An outline the depth step refuses is read again without the raised specks (RAISED_SPECK_MM2 and _GAP_MM):
    only then, as nearly every outline passes with them and finding them costs ~20 ms on the raster.
    """
    problem = _outline_depth(outline, outward, raised, measured, footprint, hidden, outside_mm, supplementary)
    if problem is None:
        return None
    despeckled = raised.without_specks(RAISED_SPECK_MM2, RAISED_SPECK_GAP_MM)
    return _outline_depth(outline, outward, despeckled, measured, footprint, hidden, outside_mm, supplementary)


def _outline_depth(
    outline: np.ndarray,
    outward: np.ndarray,
    raised: Footprint,
    measured: Footprint,
    footprint: Footprint | None,
    hidden: np.ndarray | None,
    outside_mm: float,
    supplementary: bool,
) -> CheckFailure | None:
    """check_outline_depth on one raised map."""
    inside = outline - OUTLINE_INSIDE_MM * outward
    outside = outline + outside_mm * outward
    in_known, out_known = measured.contains(inside), measured.contains(outside)
    if footprint is not None:
        in_known &= footprint.contains(inside)
        out_known &= ~footprint.contains(outside)
    in_ok = raised.contains(inside)
    out_ok = ~raised.contains(outside)
    testable = in_known & out_known
    seen = len(outline) if hidden is None else int(np.count_nonzero(~hidden))
    too_few = np.count_nonzero(testable) < MIN_TESTABLE * seen or seen < MIN_TESTABLE * len(outline) / 2
    if too_few and supplementary:
        return None
    if too_few:
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"outline not confirmed by depth: only {np.count_nonzero(testable)} of {len(outline)} outline points "
            f"({seen} in view) have measured depth on both sides",
        )
    agree = float(np.mean((in_ok & out_ok)[testable]))
    if agree < MIN_OUTLINE_AGREEMENT:
        low_inside = float(np.mean(~in_ok[testable]))
        high_outside = float(np.mean(~out_ok[testable]))
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"outline disagrees with the depth step at {100 * (1 - agree):.0f} % of its points "
            f"({100 * high_outside:.0f} % still raised {outside_mm:.2g} mm outside, {100 * low_inside:.0f} % "
            f"not raised {OUTLINE_INSIDE_MM:g} mm inside): the edge found is not the sole's edge",
        )
    if supplementary:
        return None
    return _local_disagreement(testable & ~(in_ok & out_ok), testable, "the depth step")


def _local_disagreement(bad: np.ndarray, tested: np.ndarray, evidence: str) -> CheckFailure | None:
    """A stretch of the outline (points 1 mm apart, closed) where most tested points disagree with the evidence.

    The share over the whole outline lets a notch through: a 16 mm deep cut into the sole is a few per cent
    of the outline. Scattered single disagreements are noise; most of a LOCAL_WINDOW_MM stretch is a defect.
    """
    window = np.ones(LOCAL_WINDOW_MM)
    count = np.convolve(np.concatenate([tested, tested[: LOCAL_WINDOW_MM - 1]]).astype(float), window, "valid")
    wrong = np.convolve(np.concatenate([bad, bad[: LOCAL_WINDOW_MM - 1]]).astype(float), window, "valid")
    share = wrong / np.maximum(count, 1.0)
    worst = int(np.argmax(np.where(count >= LOCAL_WINDOW_MM / 2, share, 0.0)))
    if count[worst] >= LOCAL_WINDOW_MM / 2 and share[worst] > MAX_LOCAL_DISAGREEMENT:
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the outline disagrees with {evidence} along a {LOCAL_WINDOW_MM} mm stretch ({100 * share[worst]:.0f} % "
            f"of its points, from outline point {worst}): a notch or a bulge that is not the sole's edge",
        )
    return None


def check_outline_right(
    outline: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    changed_right: np.ndarray,
    table_to_right_pixel: Callable[[np.ndarray], np.ndarray],
    right_centre: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    table_level: Footprint | None = None,
) -> CheckFailure | None:
    """The outline placed in the right image: changed just inside (at the sole's height), table just outside.

    `table_to_right_pixel(points N x 3) -> N x 2` projects table points into the rectified right image;
    `right_centre` is the right camera's centre in the table frame; `surface_height(xy N x 2) -> N` the
    measured sole height there (NaN off the sole). Outside each outline point:

    - where the right camera sees the table there (its ray passes over no part of the sole higher than
      the ray: the measured heights, and where the top has no depth, the outline's interior up to the edge
      height; the height map often stops a few mm short of a dark or rounded top edge, and a tall sole's
      edge then hid the table it was thought to show), the table RIGHT_OUTSIDE_MM out must be unchanged. `table_level`: cells whose measured points
      lie at the table's height; a changed pixel there is a shadow or a stain on the table, not sole (a sole
      reaching there would have been measured at its own height), so it does not count against the outline;
    - where the sole hides that table (the wall facing away from the camera), the point RIGHT_EDGE_OUT_MM
      out at the edge's height must be unchanged: the camera looks past the top edge there onto the table
      beyond. If the sole really reaches further out (a rounded or unmeasured edge cut off by the outline),
      that ray hits the sole. Where the left camera measured the table's height right there, the sole does
      not reach it, whatever the right pixel shows (a shadow on the table beyond).
    """
    project = table_to_right_pixel
    height, width = changed_right.shape
    edge = np.maximum(edge_height, 0.0)
    inside = np.column_stack([outline - RIGHT_INSIDE_MM * outward, edge])
    outside = np.column_stack([outline + RIGHT_OUTSIDE_MM * outward, np.zeros(len(outline))])
    beyond_edge = np.column_stack([outline + RIGHT_EDGE_OUT_MM * outward, edge])
    # The sole as the outline claims it: where the last mm of the top has no depth (the height map stops short
    # of the edge), the ray from the table just outside to the camera still passes below the top edge.
    claimed = Footprint.empty_like(outline, CLAIMED_CELL_MM, 2.0).filled(outline)
    clear = np.column_stack([outline + (RIGHT_OUTSIDE_MM - RIGHT_CLEAR_MM) * outward, np.zeros(len(outline))])
    visible = ~_hidden(clear, right_centre, surface_height, (claimed, edge))

    def sample(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        px = np.round(project(points)).astype(np.int64)
        ok = (px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)
        values = np.zeros(len(points), bool)
        values[ok] = changed_right[px[ok, 1], px[ok, 0]]
        return values, ok

    in_changed, in_ok = sample(inside)
    out_changed, out_ok = sample(outside)
    far_changed, far_ok = sample(beyond_edge)
    if table_level is not None:
        out_changed &= ~table_level.contains(outside[:, :2])
        far_changed &= ~table_level.contains(beyond_edge[:, :2])
    out_changed = np.where(visible, out_changed, far_changed)
    out_ok = np.where(visible, out_ok, far_ok)
    inside_agree = float(np.mean(in_changed[in_ok])) if np.any(in_ok) else 0.0
    outside_agree = float(np.mean(~out_changed[out_ok])) if np.count_nonzero(out_ok) > 0.2 * len(outline) else 1.0
    if inside_agree < MIN_OUTLINE_AGREEMENT or outside_agree < MIN_OUTLINE_AGREEMENT:
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the outline found in the left image does not fit the right image: {100 * inside_agree:.0f} % "
            f"of the points {RIGHT_INSIDE_MM:g} mm inside show the sole and {100 * outside_agree:.0f} % of those "
            f"outside the table (need {100 * MIN_OUTLINE_AGREEMENT:.0f} %)",
        )
    tested = in_ok & out_ok
    bad = tested & (~in_changed | out_changed)
    return _local_disagreement(bad, tested, "the right image") or _disagreeing_run(bad, "the right image")


def _disagreeing_run(bad: np.ndarray, evidence: str) -> CheckFailure | None:
    """The longest run of consecutive disagreeing outline points (closed): more than MAX_DISAGREEING_RUN is a spur or
    a notch too short for the stretch test and still deep enough to move a glue point by its tolerance."""
    runs = closed_runs(bad)
    if not runs:
        return None
    longest = max(runs, key=len)  # the first of the longest along the path, from its first agreeing point
    start, length = int(longest[0]), len(longest)
    if length <= MAX_DISAGREEING_RUN:
        return None
    return CheckFailure(
        FailureKind.OUTLINE_INCONSISTENT,
        f"the outline disagrees with {evidence} at {length} consecutive points from outline point {start} (1 mm "
        f"apart; at most {MAX_DISAGREEING_RUN}): a spur or a notch of the outline that is not the sole's edge",
    )


def hidden_from(
    table_points: np.ndarray, camera: np.ndarray, surface_height: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """Whether the camera (table frame) cannot see each table point (N x 2 or N x 3 at z = 0) past the sole."""
    return _hidden(np.column_stack([table_points[:, :2], np.zeros(len(table_points))]), camera, surface_height)


def _hidden(
    table_points: np.ndarray,
    camera: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    claimed: tuple[Footprint, np.ndarray] | None = None,
) -> np.ndarray:
    """Whether the ray from each table point (N x 3, z = 0) to the camera passes below the sole's surface.

    claimed: a region and a height per table point: where the surface has no measured height, the ray of
    point i is also below it inside the region up to height i.
    """
    # Every step's heights at once (steps x points): the same per-element arithmetic as one step at a time,
    # one lookup of the surface instead of one per step (~60).
    z = np.arange(HIDDEN_STEP_MM, HIDDEN_MAX_MM, HIDDEN_STEP_MM)[:, None]
    fraction = (z / camera[2])[:, :, None]
    base = table_points[:, :2]
    xy = (base[None, :, :] + fraction * (camera[:2] - base)[None, :, :]).reshape(-1, 2)
    height = surface_height(xy).reshape(len(z), len(base))
    below = height >= z  # NaN (no sole there) compares False
    if claimed is not None:
        region, top = claimed
        below |= np.isnan(height) & (top[None, :] >= z) & region.contains(xy).reshape(below.shape)
    return np.any(below, axis=0)


def check_height_support(names: tuple[str, ...], counts: np.ndarray, expected: float) -> CheckFailure | None:
    """The heel and toe heights' patches (`names`, their cloud points `counts`) against the points a fully measured
    patch holds (`expected`: its area over a pixel's footprint on the table): under MIN_HEIGHT_SUPPORT of them, the
    height is the few points left between glare or mismatches, not the top's."""
    for name, count in zip(names, counts, strict=True):
        if count < MIN_HEIGHT_SUPPORT * expected:
            return CheckFailure(
                FailureKind.SURFACE_NOT_MEASURED,
                f"the {name} height rests on {int(count)} measured points where its patch holds about "
                f"{expected:.0f} ({100 * count / expected:.0f} %, need {100 * MIN_HEIGHT_SUPPORT:.0f} %): glare or "
                "too little texture there; light the sole without highlights or raise the exposure",
            )
    return None


def check_glue_coverage(covered: np.ndarray) -> CheckFailure | None:
    """Glue points with measured surface under them (bool per point, see GLUE_COVER_RADIUS_MM)."""
    uncovered = 1.0 - float(np.mean(covered))
    if uncovered > MAX_GLUE_UNCOVERED:
        return CheckFailure(
            FailureKind.SURFACE_NOT_MEASURED,
            f"{100 * uncovered:.0f} % of the glue path runs where no surface was measured within "
            f"{GLUE_COVER_RADIUS_MM:g} mm (a steep or rounded edge the cameras do not see, or a top too smooth or "
            f"glary there to match; need at most {100 * MAX_GLUE_UNCOVERED:.0f} %): its heights there would not be "
            "measurements",
        )
    return None


def too_oblique(obliqueness_deg: float) -> bool:
    """Whether a rig looking at the table `obliqueness_deg` off its normal lies beyond the glue precision's
    calibration (CALIBRATED_OBLIQUENESS_DEG)."""
    return obliqueness_deg > CALIBRATED_OBLIQUENESS_DEG


def glue_sd_limit(
    tolerance_mm: float = GLUE_HEIGHT_TOLERANCE_MM,
    obliqueness_deg: float = 0.0,
    quieter_than_one_exposure: bool = False,
    exposures: int | None = None,
) -> float:
    """The most the glue heights' median expected error may be (mm) for `tolerance_mm`, on a rig that looks at the
    table `obliqueness_deg` off its normal (GLUE_TYPICAL_SD_SHARE, less where `too_oblique`);
    `quieter_than_one_exposure`: the surface was fitted on the mean of a clean camera's exposures
    (GLUE_TYPICAL_SD_SHARE_AVERAGED), of `exposures` of them where known (more than AVERAGED_FRAMES: less,
    GLUE_SD_SHARE_PER_DOUBLING)."""
    share = GLUE_TYPICAL_SD_SHARE_AVERAGED if quieter_than_one_exposure else GLUE_TYPICAL_SD_SHARE
    if quieter_than_one_exposure and exposures is not None and exposures > AVERAGED_FRAMES:
        share *= GLUE_SD_SHARE_PER_DOUBLING ** float(np.log2(exposures / AVERAGED_FRAMES))
    if too_oblique(obliqueness_deg):
        share *= OBLIQUE_SD_SHARE_FACTOR
    return share * tolerance_mm


def more_exposures_reachable(
    typical_mm: float,
    tolerance_mm: float,
    obliqueness_deg: float,
    quieter_than_one_exposure: bool,
    exposures: int | None,
) -> bool:
    """Whether a median expected error `typical_mm`, refused on the mean of a clean camera's `exposures` (None: the
    cycle's AVERAGED_FRAMES), may pass on MORE_EXPOSURES: only the sensor's noise averages, so the error falls by
    at most the square root of the exposures' ratio (the scene's own part not at all: 7 of the 15 soles the
    fortieth round re-measured on eight fell by less); beyond that the further exposures cannot help."""
    count = AVERAGED_FRAMES if exposures is None else exposures
    if not quieter_than_one_exposure or count >= MORE_EXPOSURES:
        return False
    best = typical_mm * float(np.sqrt(count / MORE_EXPOSURES))
    return best <= glue_sd_limit(tolerance_mm, obliqueness_deg, True, MORE_EXPOSURES)


def check_glue_precision(
    height_sd: np.ndarray,
    tolerance_mm: float = GLUE_HEIGHT_TOLERANCE_MM,
    obliqueness_deg: float = 0.0,
    quieter_than_one_exposure: bool = False,
    soft_edges: bool = False,
    exposures: int | None = None,
) -> CheckFailure | None:
    """The glue heights' expected errors (per point, mm) against what a glue-height tolerance of `tolerance_mm`
    allows: in the median along the path (`glue_sd_limit`, on a rig looking at the table `obliqueness_deg` off its
    normal; `quieter_than_one_exposure`: fitted on the mean of a clean camera's `exposures`), and at every point
    (GLUE_POINT_SD_SHARE); `soft_edges`: the images are soft at the sole's edge (cellctl.vision.edge_blur), which
    the refusal names first."""
    remedy = (_SOFT_EDGES_FIRST if soft_edges else "") + _COARSE_REMEDY
    if not np.any(np.isfinite(height_sd)):
        return CheckFailure(FailureKind.SURFACE_NOT_MEASURED, "the glue heights' expected error is unknown")
    typical, limit = (
        float(np.nanmedian(height_sd)),
        glue_sd_limit(tolerance_mm, obliqueness_deg, quieter_than_one_exposure, exposures),
    )
    if typical > limit:
        oblique = (
            f" on a rig looking at the table {obliqueness_deg:.1f} degrees off its normal (beyond "
            f"{CALIBRATED_OBLIQUENESS_DEG:g} the limit is smaller: mount the cameras square to the table)"
            if too_oblique(obliqueness_deg)
            else ""
        )
        on_mean = " on the mean of the exposures" if quieter_than_one_exposure else ""
        more = ""
        reachable = more_exposures_reachable(
            typical, tolerance_mm, obliqueness_deg, quieter_than_one_exposure, exposures
        )
        if reachable:
            more_limit = glue_sd_limit(tolerance_mm, obliqueness_deg, True, MORE_EXPOSURES)
            more = (
                f"; or average {MORE_EXPOSURES} exposures per cycle ([cameras] averaged_frames: at most "
                f"{more_limit:.2f} then, and the cycle takes their time)"
            )
        return CheckFailure(
            FailureKind.SURFACE_NOT_MEASURED,
            f"the sole's top is measured too coarsely for its glue heights: their expected error is {typical:.2f} mm "
            f"(median along the path{on_mean}; at most {limit:.2f} for the {tolerance_mm:g} mm tolerance{oblique}): "
            + remedy
            + more,
            MORE_EXPOSURES if reachable else None,
        )
    worst, point_limit = int(np.nanargmax(height_sd)), GLUE_POINT_SD_SHARE * tolerance_mm
    if height_sd[worst] > point_limit:
        over = int(np.count_nonzero(np.nan_to_num(height_sd) > point_limit))
        return CheckFailure(
            FailureKind.SURFACE_NOT_MEASURED,
            f"part of the sole's top is measured too coarsely for its glue heights: at glue point {worst} their expected "
            f"error is {height_sd[worst]:.2f} mm ({over} points beyond {point_limit:.2f}, half the {tolerance_mm:g} mm "
            f"tolerance; {typical:.2f} in the median along the path): " + remedy,
        )
    return None


# Where the images are soft at the sole's edge, the likeliest cause, named before the others.
_SOFT_EDGES_FIRST = "the images are soft at the sole's edge (a camera out of focus?); "
# Why a top is measured too coarsely, and what the line can do about it.
_COARSE_REMEDY = (
    "too little texture on the top, too much image noise or a camera out of focus; light the sole more brightly or "
    "raise the exposure, check the cameras' focus on the table, or set [measure] glue_height_tolerance_mm to what the "
    "dispenser really allows"
)


def glue_deviation_limit(depth_per_pixel_mm: float | None) -> float:
    """How far (mm) a glue point may lie from its own patch height on a rig whose disparity pixel spans
    `depth_per_pixel_mm` of depth at the table: GLUE_MAX_DEVIATION_MM, grown in proportion on a rig coarser than
    the one it was set on (never below it; None: unknown, as set)."""
    if depth_per_pixel_mm is None or not np.isfinite(depth_per_pixel_mm):
        return GLUE_MAX_DEVIATION_MM
    return GLUE_MAX_DEVIATION_MM * max(1.0, depth_per_pixel_mm / GLUE_DEVIATION_DEPTH_PX_MM)


def check_glue_path(
    points: np.ndarray,
    normals: np.ndarray,
    raw_z: np.ndarray,
    patch_normals: np.ndarray,
    sole_heights: tuple[float, float],
    spacing_mm: float,
    depth_normals: Callable[[np.ndarray], np.ndarray],
    deviation_limit_mm: float = GLUE_MAX_DEVIATION_MM,
) -> CheckFailure | None:
    """Glue points (N x 3) and normals against the sole's height range, their own samples (at most
    `deviation_limit_mm` apart: `glue_deviation_limit`) and the surface: the patches' normals along the path, and
    `depth_normals(index)`, the depth's own normals at the glue points `index` (glue_path.depth_normals; NaN:
    unknown): at the points where the patches disagree grossly, and along the path for the slope across it
    (`check_glue_tilt`)."""
    z = points[:, 2]
    low, high = sole_heights[0] - GLUE_HEIGHT_MARGIN_MM, sole_heights[1] + GLUE_HEIGHT_MARGIN_MM
    outside = np.flatnonzero((z < max(low, 0.0)) | (z > high))
    if outside.size:
        k = int(outside[np.argmax(np.abs(z[outside] - np.clip(z[outside], low, high)))])
        return _glue(
            f"glue point {k} at {z[k]:.1f} mm height is outside the sole's heights {sole_heights[0]:.1f}.."
            f"{sole_heights[1]:.1f} mm"
        )
    step = np.abs(np.diff(np.append(z, z[:1])))
    if step.max() > GLUE_MAX_SLOPE * spacing_mm:
        k = int(np.argmax(step))
        return _glue(f"glue path height jumps {step[k]:.1f} mm between points {k} and {(k + 1) % len(z)}")
    deviation = np.abs(z - raw_z)
    if np.nanmax(deviation) > deviation_limit_mm:
        k = int(np.nanargmax(deviation))
        return _glue(
            f"glue point {k} is {deviation[k]:.1f} mm from the surface measured there: the surface is not "
            "continuous along the path"
        )
    if normals[:, 2].min() < MIN_GLUE_NZ:
        return _glue(f"a glue normal is {np.degrees(np.arccos(normals[:, 2].min())):.0f} degrees off vertical")
    angle = _angles(normals, patch_normals)
    suspect = np.flatnonzero(angle > GLUE_MAX_NORMAL_DEG)
    depth = depth_normals(np.arange(len(normals)))
    if suspect.size:
        depth_angle = _angles(normals[suspect], depth[suspect])
        against_both = ~(depth_angle <= GLUE_MAX_NORMAL_DEG)  # NaN (no depth there): the patches' word stands
        if against_both.any():
            worst = int(np.argmax(np.where(against_both, angle[suspect], -1.0)))
            k, depth = int(suspect[worst]), depth_angle[worst]
            against = f"{depth:.0f} from the depth's plane there" if np.isfinite(depth) else "no depth there"
            return _glue(
                f"glue normal {k} is {angle[k]:.0f} degrees from the surface fitted around it and {against} "
                f"(limit {GLUE_MAX_NORMAL_DEG:g})"
            )
    return check_glue_tilt(points[:, :2], normals, patch_normals, depth, spacing_mm)


def check_glue_tilt(
    path_xy: np.ndarray, normals: np.ndarray, patch_normals: np.ndarray, depth_normals: np.ndarray, spacing_mm: float
) -> CheckFailure | None:
    """The glue normals' slope across the closed, counter-clockwise path `path_xy` against the surface's own around
    each point: the patches' normals and the depth's planes (N x 3, NaN: unknown). Refused where the top under the
    path leans across it against the glue normals by more than GLUE_MAX_TILT_PATH in the patches' median along the
    whole path (the depth's median leaning the same way), or by more than
    GLUE_MAX_TILT_STRETCH in both along some GLUE_TILT_STRETCH_MM of it: a top that curves near its edge."""
    outward = outward_normals(path_xy)
    glue = _across(normals, outward)
    patch, depth = _across(patch_normals, outward) - glue, _across(depth_normals, outward) - glue
    over_path, depth_over_path = _median_of_known(patch), _median_of_known(depth)
    confirmed = over_path * depth_over_path > 0.0  # NaN: not confirmed
    reach = _stretch_reach(len(glue), spacing_mm)
    stretch = np.nan_to_num(_agreed(running_median(patch, reach), running_median(depth, reach)))
    worst = int(np.argmax(np.abs(stretch)))
    if confirmed and abs(over_path) > GLUE_MAX_TILT_PATH:
        where, tilt, limit = "along the whole path", over_path, GLUE_MAX_TILT_PATH
    elif abs(stretch[worst]) > GLUE_MAX_TILT_STRETCH:
        where, tilt, limit = (
            f"along {GLUE_TILT_STRETCH_MM:g} mm of it round glue point {worst}",
            stretch[worst],
            GLUE_MAX_TILT_STRETCH,
        )
    else:
        return None
    way = "rises towards" if tilt > 0 else "falls towards"
    return _glue(
        f"the sole's top under the glue line {way} its edge {np.degrees(np.arctan(abs(tilt))):.0f} degrees more "
        f"steeply than the glue normals say {where} (the surface fitted round each glue point says so and the "
        f"depth's own planes lean the same way; limit {np.degrees(np.arctan(limit)):.1f}): a raised lip or a top "
        "curving near its edge, which the glue normals, whose slope across the path is taken over a wider base, do "
        "not follow; set the recipe's [glue] offset_mm to where the top is level"
    )


def check_glue_rise(rise: np.ndarray, spacing_mm: float) -> CheckFailure | None:
    """The glue line's rise above the top's course further in (per point, mm, NaN: not read; glue_path.edge_rise):
    refused where its running median over GLUE_TILT_STRETCH_MM of the path exceeds GLUE_MAX_RISE_MM."""
    reach = _stretch_reach(len(rise), spacing_mm)
    along = running_median(rise, reach, quorum=max(1, reach // 2))
    if not np.any(along > GLUE_MAX_RISE_MM):
        return None
    worst = int(np.nanargmax(along))
    return _glue(
        f"the glue line stands {along[worst]:.1f} mm above the course of the sole's top further in along "
        f"{GLUE_TILT_STRETCH_MM:g} mm of it round glue point {worst} (limit {GLUE_MAX_RISE_MM:g}): a raised lip or heel "
        "cup, whose slope under the glue line the glue normals do not follow; set the recipe's [glue] offset_mm to "
        "where the top is level"
    )


def _stretch_reach(count: int, spacing_mm: float) -> int:
    """Glue points either side of each that span GLUE_TILT_STRETCH_MM of a closed path of `count` points
    `spacing_mm` apart, at most the whole path."""
    return int(min(round(GLUE_TILT_STRETCH_MM / 2.0 / spacing_mm), (count - 1) // 2))


def _across(normals: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Per point the surface's slope (rise per mm) towards `outward` of unit upward normals (NaN: unknown)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return -np.sum(normals[:, :2] * outward, axis=1) / normals[:, 2]


def _median_of_known(values: np.ndarray) -> float:
    """The median of the known (finite) values; NaN if none is."""
    known = values[np.isfinite(values)]
    return float(np.median(known)) if known.size else float("nan")


def _agreed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where a and b have one sign, the one nearer zero (signed); 0 where they disagree or either is unknown (NaN)."""
    smaller = np.where(np.abs(a) < np.abs(b), a, b)
    return np.where(np.sign(a) * np.sign(b) > 0, smaller, 0.0)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (degrees) between unit vectors row by row; NaN where either is unknown."""
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def _glue(reason: str) -> CheckFailure:
    return CheckFailure(FailureKind.GLUE_PATH_INCONSISTENT, reason)
