"""The glue path: a closed line inside the sole's edge, lifted onto its top surface, with its normals."""

from __future__ import annotations

import numpy as np

from cellctl.vision.closed_path import along_kernel, outward_normals, resample_closed, smooth_along
from cellctl.vision.defaults import GLUE_OFFSET_MM, GLUE_SPACING_MM
from cellctl.vision.local_fit import disc_overlap, slope_gradients, upward_normals
from cellctl.vision.sole_result import GluePath
from cellctl.vision.surface import (
    PATH_NOISE_LAG,
    PATH_SMOOTHING_MM,
    RingSamples,
    SoleSurface,
    path_heights,
    path_noise,
)

GLUE_FIT_RADIUS_MM = 4.0
GLUE_NORMAL_BASE_MM = 15.0  # second ring of height samples this far inside the path, for the normals (see below)
# A ring of height samples this far inside the path that the heights' planes may span, with the normals' ring
# (surface.path_heights: chosen where their expected error, bias against the path's own fit included, is the
# smallest). The glue points' own patches, 2 mm from the edge, scatter ~1.5 x as much as those a few mm further in
# on black soles (0.43-0.54 vs 0.29-0.38 mm rms, 16 standard soles; /work/notes/s15/rings.py) and their errors run
# along the edge; a plane across the path and the two rings averages them with nearly independent ones (6 mm
# apart, the 4 mm patches barely overlap; a plane through the path and one ring alone passes through the path's own
# mean). This ring is sampled at every GLUE_RING_STRIDE-th glue point: the planes are 6-12 mm wide, and each sample
# is a patch fit the cycle pays for. A rounded top edge falls towards the path, which bends a plane across the
# rings: there the bias against the path's own fit rules it out.
GLUE_HEIGHT_RING_MM = 6.0
GLUE_RING_STRIDE = 2
GLUE_OUTLIER_MM = 1.5  # a lone patch height this far from its neighbours' median is a failed fit
GLUE_NORMAL_SMOOTHING_MM = 12.0  # slopes for the normals: width of the local plane fit
GLUE_NORMAL_TIP_SMOOTHING_MM = 16.0  # round a tip: width of the quadratic fit (local_fit.TIP_TURN_DEG)
# The patch-overlap noise model (sample_variance) against the slopes' true errors: over the 113 measured soles of
# the three matrix sets (72k gradient components) the cubic fits' errors are 1.45 x their propagated sd
# (median-based; 1.25 on black soles, where the noise dominates) and 1.68 x at the 95th percentile (the standard
# 20: 1.42, 1.65; /work/notes/wrong6-diag/calib.py): the matcher's error is correlated beyond the patches'
# overlap. The choice between the fits is taken at break-even, so the noise is taken at its tail: variances
# scaled by this ratio squared (1.5 and 2.0 give the same verdicts; 1.5 let noise flip a few worst points to
# the cubic, up to +1 degree on a plain black sole). The heights' choice of fit (surface.path_heights) takes the
# noise the same way.
GLUE_SLOPE_NOISE_RATIO = 1.75
# The glue normals' consistency check's second reference (checks.check_glue_path): the plane of the depth's own points
# this far round a glue point, smoothed along the path like the patches' normals. Independent of the image fits, whose
# tilts a colour edge on the sole pulls (matrix sole 2057's rim: 55 degrees from a glue normal 2.2 degrees from the
# truth, where the depth's plane was 10 degrees off); 6 mm: the depth's noise at 4 mm left 25 degrees at the worst of
# the matrix's black soles, this 18 (sets 2000 and 4000, 86 valid results; /work/notes/s16/normdiag.py).
GLUE_DEPTH_NORMAL_RADIUS_MM = 6.0
# The normals' slope across the path is a difference of heights GLUE_NORMAL_BASE_MM apart (_slopes): on a top curved
# across (z = k d^2 at d mm in from the path) that is the slope halfway in, off the path's own by k x that base. The
# glue line's rise above the line through the two rings (edge_rise) is k x GLUE_HEIGHT_RING_MM x GLUE_NORMAL_BASE_MM
# there, so rise / GLUE_HEIGHT_RING_MM is the slope the normals miss. A dished footbed 3-6 mm deep (`dished-top`, 32
# valid results from 48100 and 48300) missed 0.018-0.043 outward in the median (1.0-2.5 degrees; 48110 published
# WRONG at 5.2 degrees, a noise spike along the path on top), which the path's median rise / 6 read as 0.013-0.034;
# a domed top the other way. Taken from the whole path's median: the rise at single points is noise (corrected point
# by point over 40-80 mm, the worst normal of plain tops grew by up to 4 degrees). That median strays too: on the 148
# valid results of the four fresh sets it read up to 0.024 (p90 0.013) where their normals missed at most 0.022 and
# mostly the other way (colour edges of rims and logos pull the patches, black rubber's noise); less 0.005 it made 13
# of them worse by over 0.005 (a black rim's worst normal 3.2 -> 4.0 degrees), less GLUE_BEND_DEADBAND none
# (/work/notes/s37/probe_rise.py). So a dish's bias is only partly taken back (0.033 -> 0.021 in the median): the
# estimate cannot tell a shallow curve from a colour edge. A rise beyond GLUE_BEND_MAX_RISE_MM is no gentle curve but
# a lip, which the lean and rise checks judge on the normals as fitted (checks.check_glue_tilt, check_glue_rise).
GLUE_BEND_DEADBAND = 0.015
GLUE_BEND_MAX_RISE_MM = 0.3


def glue_path(
    surface: SoleSurface,
    outline: np.ndarray,
    centroid: np.ndarray,
    axis: np.ndarray,
    offset_mm: float = GLUE_OFFSET_MM,
    spacing_mm: float = GLUE_SPACING_MM,
) -> tuple[GluePath | None, str | None]:
    """The outline moved `offset_mm` inward, resampled every `spacing_mm`, lifted onto the top surface.

    Moving each point along the inward normal is exact for outlines whose curvature radius exceeds the
    offset everywhere, which holds for soles (the tightest curve, the toe, has a radius of several cm).
    Heights are sampled on the path and on a second ring GLUE_NORMAL_BASE_MM further in; the normal comes
    from a plane fitted to both around each point, or where the slope changes along the path a plane plus that
    change, whichever has the smaller expected error (a patch's own tilt is too noisy on a weakly textured
    sole: ~10 degrees).
    """
    resampled = resample_closed(outline, 0.25)
    inward = -outward_normals(resampled)
    path_xy = resample_closed(resampled + offset_mm * inward, spacing_mm)
    start = int(np.argmin((path_xy - centroid) @ axis))  # the heel end
    path_xy = np.roll(path_xy, -start, axis=0)
    path_inward = -outward_normals(path_xy)
    inner_xy = path_xy + GLUE_NORMAL_BASE_MM * path_inward
    ring_xy = (path_xy + GLUE_HEIGHT_RING_MM * path_inward)[::GLUE_RING_STRIDE]
    n = len(path_xy)
    # The patch fits on two threads (SoleSurface.sample(parallel=True)): the same samples as on one.
    samples = surface.sample(np.vstack([path_xy, inner_xy, ring_xy]), GLUE_FIT_RADIUS_MM, parallel=True)
    missing = np.flatnonzero(~np.isfinite(samples.z[:n]))
    if missing.size:
        x, y = path_xy[missing[0]]
        return None, (
            f"glue path: no top surface measured near ({x:.1f}, {y:.1f}) mm ({missing.size} of {n} path points)"
        )
    # Neighbouring patches overlap but their noise does not all average out; the surface is smooth, so a
    # local fit to the path's samples around each point takes the rest (cellctl.vision.local_fit: unbiased
    # for a sloping surface also where the path turns round a pointed end), of the width and shape whose
    # expected error (the samples' noise, the fit's bias on a curved top) is smallest (surface.path_heights).
    sigma = PATH_SMOOTHING_MM / spacing_mm
    raw = without_single_outliers(samples.z[:n])
    inner = without_single_outliers(samples.z[n : 2 * n])
    path_variance = GLUE_SLOPE_NOISE_RATIO**2 * sample_variance(path_xy, raw, spacing_mm)
    inner_variance = GLUE_SLOPE_NOISE_RATIO**2 * sample_variance(inner_xy, inner, spacing_mm)
    ring_z = without_single_outliers(samples.z[2 * n :])
    ring_variance = GLUE_SLOPE_NOISE_RATIO**2 * sample_variance(ring_xy, ring_z, GLUE_RING_STRIDE * spacing_mm)
    rings = RingSamples(
        np.vstack([inner_xy, ring_xy]), np.concatenate([inner, ring_z]), np.concatenate([inner_variance, ring_variance])
    )
    # One after the other on this thread: beside each other on two threads (tried) they are two Python threads
    # making hundreds of short numpy calls each, handing the GIL back and forth, and the demo's glue path then
    # stalled for 200-350 ms in some cycles (max / median worse in 9 of 10 A/B pairs, docs/benchmarks.md).
    z, height_sd = path_heights(path_xy, raw, path_variance, rings)
    normals = _slopes(path_xy, path_inward, inner_xy, raw, inner, path_variance, inner_variance, spacing_mm)
    patch_normals = smooth_along(samples.normals[:n], sigma)
    patch_normals /= np.linalg.norm(patch_normals, axis=1, keepdims=True)
    rise = edge_rise(raw, ring_z, inner)
    normals = tilted(normals, -path_inward, across_bend(rise))
    return GluePath(np.column_stack([path_xy, z]), normals, True, raw, patch_normals, height_sd, rise), None


def edge_rise(raw: np.ndarray, ring: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """Per glue point how far (mm) its patch height `raw` stands above the line through the rings' heights inside it
    (`ring`, GLUE_HEIGHT_RING_MM in, every GLUE_RING_STRIDE-th point; `inner`, GLUE_NORMAL_BASE_MM in), extrapolated to
    the path; NaN where no ring point was sampled. A top curved as a sole's is (its dome or cup, a toe's spring) keeps
    it within a few tenths; a raised lip or heel cup lifts it by most of the lip's height."""
    at = np.arange(0, len(raw), GLUE_RING_STRIDE)[: len(ring)]
    course = ring + (ring - inner[at]) * GLUE_HEIGHT_RING_MM / (GLUE_NORMAL_BASE_MM - GLUE_HEIGHT_RING_MM)
    rise = np.full(len(raw), np.nan)
    rise[at] = raw[at] - course
    return rise


def across_bend(rise: np.ndarray) -> float:
    """The slope (rise per mm, outward) that the glue normals miss on a top curved across, from the glue line's
    `edge_rise` (per point, mm, NaN: not read): the whole path's median over GLUE_HEIGHT_RING_MM, less
    GLUE_BEND_DEADBAND towards zero; 0 where that median is unknown or beyond GLUE_BEND_MAX_RISE_MM."""
    known = rise[np.isfinite(rise)]
    median = float(np.median(known)) if known.size else float("nan")
    if not abs(median) <= GLUE_BEND_MAX_RISE_MM:  # unknown (NaN) or a lip
        return 0.0
    bend = median / GLUE_HEIGHT_RING_MM
    return float(np.sign(bend) * max(abs(bend) - GLUE_BEND_DEADBAND, 0.0))


def tilted(normals: np.ndarray, outward: np.ndarray, slope: float) -> np.ndarray:
    """Unit upward normals whose surfaces rise `slope` (per mm) more towards `outward` (unit, in the plane)."""
    if slope == 0.0:
        return normals
    return upward_normals(-normals[:, :2] / normals[:, 2:3] + slope * outward)


def depth_normals(surface: SoleSurface, path_xy: np.ndarray, index: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Unit normals (len(index) x 3; NaN where the cloud has too few points) of the depth's planes
    (SoleSurface.cloud_planes, GLUE_DEPTH_NORMAL_RADIUS_MM) at the glue points `index` of the closed path path_xy,
    smoothed along it as the patches' normals are (closed_path.smooth_along, PATH_SMOOTHING_MM); only the points
    the smoothing reads are fitted."""
    kernel = along_kernel(PATH_SMOOTHING_MM / spacing_mm, len(path_xy))
    radius = len(kernel) // 2
    around = (np.asarray(index)[:, None] + np.arange(-radius, radius + 1)[None]) % len(path_xy)
    fitted, inverse = np.unique(around, return_inverse=True)
    z, planes = surface.cloud_planes(path_xy[fitted], GLUE_DEPTH_NORMAL_RADIUS_MM)
    which = inverse.reshape(around.shape)
    weights = kernel[None] * np.isfinite(z)[which]
    summed = np.einsum("kw,kwc->kc", weights, planes[which])
    length = np.linalg.norm(summed, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 0.0, summed / length, np.nan)


def _slopes(
    path_xy: np.ndarray,
    path_inward: np.ndarray,
    inner_xy: np.ndarray,
    raw: np.ndarray,
    inner: np.ndarray,
    path_variance: np.ndarray,
    inner_variance: np.ndarray,
    spacing_mm: float,
) -> np.ndarray:
    """The glue path's unit normals from its samples' heights (raw, on path_xy) and the inner ring's (inner)."""
    # The normal turns slowly along a sole's edge but slopes are differences of noisy heights: the plane for
    # it is fitted wider, over the path's samples and the ring GLUE_NORMAL_BASE_MM further in (the slope across).
    # The slope across is a difference of heights over that base: on the weak texture of black soles 10 mm
    # left 5-6 degrees of noise at the worst point; 15 mm brought every one of seven matrix soles' worst
    # normal down (black: 5.1 -> 5.0, 6.1 -> 4.1, 4.6 -> 3.6, 3.7 -> 2.3 degrees), a sole's top being far
    # flatter over 15 mm than the tolerance's 5 degrees.
    # Where the slope changes along the path within the fit (a tall sole's heel seat running into its waist)
    # the plane takes up the slope a few mm away; there the fit adds the slope's change along the path, and round
    # a tip (a toe rising to it) a wider full quadratic, where that lowers the expected error
    # (cellctl.vision.local_fit.slope_gradients).
    variance = np.concatenate([path_variance, inner_variance])
    gradient, _ = slope_gradients(
        path_xy,
        np.column_stack([path_inward[:, 1], -path_inward[:, 0]]),  # the tangent
        np.vstack([path_xy, inner_xy]),
        np.concatenate([raw, inner]),
        variance,
        GLUE_NORMAL_SMOOTHING_MM,
        spacing_mm,
        GLUE_NORMAL_TIP_SMOOTHING_MM,
    )
    return upward_normals(gradient)


def sample_variance(xy: np.ndarray, z: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Each patch height's noise variance (mm^2) along a closed path of samples xy, `spacing_mm` apart (nominal),
    times its correlation with the samples around it (the sum of the correlations: a wide fit's variance is then
    sum(row^2 x this), cellctl.vision.local_fit.slope_gradients).

    Patches of GLUE_FIT_RADIUS_MM closer than two radii share pixels; with independent pixel noise their heights
    correlate as the discs overlap (local_fit.disc_overlap). surface.path_noise takes second differences at
    PATH_NOISE_LAG samples as if the samples were independent; the shared part cancels there, so the sample's
    noise is path_noise / sqrt(1 - 4/3 rho(lag) + 1/3 rho(2 lag))."""
    lag = PATH_NOISE_LAG * spacing_mm
    seen = 1.0 - (4.0 * disc_overlap(lag, GLUE_FIT_RADIUS_MM) - disc_overlap(2.0 * lag, GLUE_FIT_RADIUS_MM)) / 3.0
    variance = path_noise(z, xy=xy) ** 2 / float(seen)
    correlated = np.ones(len(z))
    for k in range(1, len(z) // 2):
        rho = disc_overlap(np.linalg.norm(xy - np.roll(xy, k, axis=0), axis=1), GLUE_FIT_RADIUS_MM)
        rho_back = disc_overlap(np.linalg.norm(xy - np.roll(xy, -k, axis=0), axis=1), GLUE_FIT_RADIUS_MM)
        if not (rho.any() or rho_back.any()):
            break
        correlated += rho + rho_back
    return variance * correlated


def without_single_outliers(z: np.ndarray, limit_mm: float = GLUE_OUTLIER_MM) -> np.ndarray:
    """Heights along a closed path with isolated bad patch fits replaced by their neighbours' median.

    One patch fit can fail (a highlight, a mismatch) and smoothing would spread it over its neighbours;
    a lone value that departs from the median of the five around it is replaced. Two or more in a row are
    kept: that is the surface, or a fault the self-check must see (cellctl.vision.checks).
    """
    window = np.stack([np.roll(z, k) for k in (-2, -1, 0, 1, 2)])
    # NaN where a window has no height at all (nanmedian would warn, from a worker thread, into the log)
    some = np.isfinite(window).any(axis=0)
    median = np.full(z.shape, np.nan)
    median[some] = np.nanmedian(window[:, some], axis=0)
    bad = ~(np.abs(z - median) <= limit_mm)  # NaN counts as bad
    lone = bad & ~np.roll(bad, 1) & ~np.roll(bad, -1)
    return np.where(lone, median, z)
