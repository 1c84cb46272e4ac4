"""Local plane fits of scattered surface heights: height and gradient at query points.

The glue path's heights and normals come from surface samples along the path (and a ring further in).
Smoothing them along the path's arc length biases both where the path turns sharply: at a pointed toe
that rises towards its tip, the tip is a peak of height along the arc and a Gaussian lowers it (by ~1 mm
on simulated soles), and the slopes of the two sides cancel. A plane fitted by weighted least squares in
the table plane has no such bias: a surface that is linear around the query point, however the samples lie
around it, is fitted exactly.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# Weight of a zero gradient (mm^2, like a sample at that squared distance): keeps a fit over samples along
# a nearly straight line (the path alone) stable; it shrinks slopes by ~1 / (spread of the samples in mm^2
# about their weighted mean): 6 % at a 4 mm width.
GRADIENT_RIDGE_MM2 = 1.0
# The same for the normals' fits (slope_gradients), whose samples always span the path and its ring 15 mm in:
# the across slope is fixed by that base, and the samples' spread across is only ~50 mm^2 (the path outweighs
# the ring), so GRADIENT_RIDGE_MM2 shrank it by 1.7 % (median over four sets' valid results, fitted on the true
# heights; 0.4 degrees on a 25 degree slope), and the worst normals of the small-sole sets were 0.15-0.3 degrees
# further off (37512's, at a knee where the shrinking happened to offset the fit's bias, is 0.1 degrees nearer).
# A tenth of it still holds a fit whose ring has no heights near the point (the path's line alone).
SLOPE_RIDGE_MM2 = 0.1
# Queries per pass of the fits over all samples (slope_gradients; surface.path_heights): each pass works on
# arrays of this many rows by the samples (32 x 702 x 8 B = 180 kB for a 351-point path and its inner ring), which
# stay in a core's L2 cache (1 MB on the cell PC's Zen 4), where whole K x M arrays (2 MB each for that path, ten
# of them) went to memory: measured 26 -> 9 ms for slope_gradients on that path. Every query's arithmetic is the
# same in any pass (each row of the work arrays is its own), so the results are bit for bit those of one pass.
QUERY_CHUNK = 32
# A pass's fits read only the samples within this many widths (Gaussian sigma) of its queries' bounding box: one
# further from every query weighs < exp(-18) = 2e-8 of a sample at the query, so leaving it out moves a fit by
# ~1e-8 of the heights' spread, while a pass of 32 consecutive points of a sole's path then reads about a third
# of the path's and rings' samples instead of all of them (glue path stage 130 -> ~100 ms: issue 11, session 16).
FIT_REACH_SIGMAS = 6.0


def local_planes(at: np.ndarray, xy: np.ndarray, z: np.ndarray, sigma_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Height (K) and gradient (K x 2) at table points `at` (K x 2) of planes fitted to samples (xy M x 2, z M).

    Gaussian weights of width `sigma_mm` on the distance in the table plane; NaN samples are left out; a
    query with no sample within reach gets NaN.
    """
    finite = np.isfinite(z)
    xy, z = xy[finite], z[finite]
    # Gaussian weights (K x M) of the squared distances in the table plane, in place.
    w = np.subtract.outer(at[:, 0], xy[:, 0])
    w *= w
    dy = np.subtract.outer(at[:, 1], xy[:, 1])
    dy *= dy
    w += dy
    w /= -2.0 * sigma_mm**2
    np.exp(w, out=w)
    # The weighted sums over the samples as one K x M by M x 9 product: moments about the samples' mean c,
    # shifted to each query point (sum w (p - a) = sum w (p - c) - s (a - c), and so on); the same sums as
    # over the K x M x 2 offsets (to ~1e-13 relative), without per-query loops over them.
    centre = xy.mean(axis=0) if len(xy) else np.zeros(2)
    u, v = (xy - centre).T
    a, b = (at - centre).T
    m = w @ np.column_stack([np.ones_like(u), u, v, u * u, u * v, v * v, z, u * z, v * z])
    s, su, sv, suu, suv, svv, sz, suz, svz = m.T
    sd = np.column_stack([su - s * a, sv - s * b])
    sdd = np.empty((len(at), 2, 2))
    sdd[:, 0, 0] = suu - 2.0 * a * su + s * a * a
    sdd[:, 0, 1] = sdd[:, 1, 0] = suv - a * sv - b * su + s * a * b
    sdd[:, 1, 1] = svv - 2.0 * b * sv + s * b * b
    sdd += GRADIENT_RIDGE_MM2 * s[:, None, None] * np.eye(2)
    normal = np.empty((len(at), 3, 3))
    normal[:, 0, 0], normal[:, 0, 1:], normal[:, 1:, 0], normal[:, 1:, 1:] = s, sd, sd, sdd
    rhs = np.column_stack([sz, suz - a * sz, svz - b * sz])
    ok = s > 1e-6
    solution = np.full((len(at), 3), np.nan)
    solution[ok] = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
    return solution[:, 0], solution[:, 1:]


# The glue normals' plane is wide (12 mm) for the noise of black rubber, but a plane that wide averages the slope
# over the fit: where a sole's top changes its slope along the path (a tall sole's flat heel seat running into
# the rising waist) it takes up the slope a few mm away (5.4 degrees off on held-out 3002). Adding the slope's
# change along the path (terms u^2 and u^3 in the distance u along the path's tangent) removes that bias but
# costs noise, so each point takes whichever of the two fits has the smaller expected error: the cubic where
# the two differ by more than the noise explains (the plane's bias squared, estimated as the squared difference
# less its noise variance, exceeds the cubic's extra variance). The noise variance is propagated through both
# fits with the samples' own noise, correlated between samples as their image patches overlap.
FOLD_TURN_DEG = 60.0  # the cubic only where the path turns less than this within the fit's reach (see below)
# Round a sole's tip the path folds back, and there the top is curved across the path: a toe rising to its tip
# (toe spring), the dome across the sole. A plane through the path and its ring 15 mm in takes the mean slope
# between the two, not the slope at the path: 4.7-5.0 degrees off at the toe tips of small soles (37508 and 37521,
# where the same fit on the true heights gives the same error: it is bias, not noise). Where the path turns by
# more than TIP_TURN_DEG within the fit's reach, its samples lie at many distances in from the path as well as
# along it, so a full quadratic is determined there; fitted wider than the plane (glue_path passes 16 mm against
# 12), it is taken where it lowers the expected error, as the cubic is. Over the 365 valid results of twelve sets
# (session 33's records, /work/notes/s33/replay.py) those two tips' worst normals fell to 2.5 and 2.9 degrees, the
# mean of the soles' worst from 2.13 to 2.05 (with SLOPE_RIDGE_MM2), and no sole's worst rose by more than 0.55
# degrees (38041: 1.9 to 2.4). A 12 mm quadratic (its noise) or one taken where the path turns by 30-50 degrees
# from the point (a tall heel's knee beside its cap) put soles past 5 degrees; a total turn of 60 degrees did
# about as well as 90; 120 missed the tips.
TIP_TURN_DEG = 90.0
# Where a sole's top starts to bend (a tall heel's flat seat running into its waist, a toe spring's start) its
# curvature jumps, and the cubic along the path, smooth through the jump, is biased a few mm before it: 37512's worst
# normal (small and narrow, a 29.8 mm heel) was 4.9 degrees off on the true heights alone, 5.3-5.4 measured, within
# 1.2 sd of its difference to any narrower fit, so no choice between linear fits by their noise could see it. A knee
# is a model of its own: z = a + g . d + c ((s (u - u0))_+)^2, flat one side of a knot u0 and curving the other
# (s = +1 or -1), tried at knots KNEE_KNOT_STEP_MM apart within KNEE_KNOT_REACH_MM either side along the path. Where
# the cubic was taken, the best knee replaces it if its weighted residual is below KNEE_RSS_RATIO of the cubic's: it
# has one term fewer, so on a smooth top or in noise it fits no better (black soles' residuals are their noise, the
# ratio near 1). Over the 365 valid results of session 33's records (/work/notes/s33/knot.py): 37512 5.37 -> 4.23,
# soles' worst beyond 4 degrees 6 -> 4, mean 2.05 -> 2.03, no sole's worst up by more than 0.3 (33047: 1.47 -> 1.77);
# at a ratio of 1.0 or 0.9 noise took knees on a few smooth tops (37401: 2.77 -> 3.94), 0.7 and 0.6 did about as
# 0.8 (37512 4.23 and 4.27). Knots within one fit width either side gave the same over those 365 as within 20 mm,
# in 60 % of the time; knots 4 mm apart put two more soles past 3 degrees. At 0.8 a knee still fitted the noise of
# a dished black top (48110: ratios 0.73-0.79 along 10 mm, the knee 5.2 degrees off where the cubic was 3.3 and the
# plane 1.7; published 5.04 degrees off). At 0.7 it reads 4.02, and over the 242 valid results of the four fresh
# sets 39000-46000 and the waisted, dished, domed and sprung runs, and the standard 20, no result's validity changed
# and no sole's worst normal rose by more than 0.32 degrees (0.6 on the sets and dishes: the same, 0.22;
# docs/sole-benchmark.md, thirty-seventh round).
KNEE_KNOT_STEP_MM = 2.0
KNEE_KNOT_REACH_MM = 12.0
KNEE_RSS_RATIO = 0.7


def upward_normals(gradient: np.ndarray) -> np.ndarray:
    """Unit normals (K x 3, pointing up) of surfaces z = gx x + gy y + c with the gradients (gx, gy) (K x 2)."""
    normals = np.column_stack([-gradient, np.ones(len(gradient))])
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def disc_overlap(distance: np.ndarray | float, radius: float) -> np.ndarray:
    """Shared area of two discs of `radius` whose centres are `distance` apart, as a share of one disc's area.

    The correlation of two patch heights fitted over overlapping image discs with independent pixel noise."""
    x = np.clip(np.asarray(distance, np.float64) / (2.0 * radius), 0.0, 1.0)
    return (2.0 / np.pi) * (np.arccos(x) - x * np.sqrt(1.0 - x * x))


def known_variance(variance: np.ndarray) -> np.ndarray:
    """`variance` with its unknown (NaN) entries taken as the median of the known ones (0 if none is known)."""
    return np.where(np.isfinite(variance), variance, np.nanmedian(variance) if np.isfinite(variance).any() else 0.0)


def unfolded(tangent: np.ndarray, sigma_mm: float, spacing_mm: float) -> np.ndarray:
    """Per point of a closed path (unit tangents K x 2, samples `spacing_mm` apart): whether the path turns less
    than FOLD_TURN_DEG within 2 sigma either side, so that the distance along its tangent means something over a
    fit of width `sigma_mm` (round a pointed end it mixes both sides)."""
    angles = _tangent_windows(tangent, sigma_mm, spacing_mm)
    turn = np.min(np.cos(angles - angles[:, angles.shape[1] // 2, None]), axis=1)
    return turn > np.cos(np.radians(FOLD_TURN_DEG))


def round_a_tip(tangent: np.ndarray, sigma_mm: float, spacing_mm: float) -> np.ndarray:
    """Per point of a closed path (unit tangents K x 2, samples `spacing_mm` apart): whether the path turns by more
    than TIP_TURN_DEG in all within 2 sigma either side (any two of its tangents there that far apart). With the
    tangents' directions unwrapped along the path (steps below 180 degrees), two are more than 90 degrees apart
    exactly where the window's directions span more than 90 degrees: every difference lies within the span, and a
    span beyond 90 degrees is a difference beyond 90 or, past 270, is walked in steps of under 180 that land between."""
    angles = _tangent_windows(tangent, sigma_mm, spacing_mm)
    return np.ptp(angles, axis=1) > np.radians(TIP_TURN_DEG)


def _tangent_windows(tangent: np.ndarray, sigma_mm: float, spacing_mm: float) -> np.ndarray:
    """Per point of a closed path: the directions (radians, K x (2 reach + 1)) of its tangents within 2 sigma either
    side, unwrapped along the path so that each window is continuous (the path closes on itself: the window round
    its seam reads past it)."""
    reach = max(1, int(round(2.0 * sigma_mm / spacing_mm)))
    around = tangent[np.arange(-reach, len(tangent) + reach) % len(tangent)]
    angles = np.unwrap(np.arctan2(around[:, 1], around[:, 0]))
    return np.lib.stride_tricks.sliding_window_view(angles, 2 * reach + 1)


class _Offsets(NamedTuple):
    """A pass's samples seen from each of its queries (K x M): offsets in the table plane, Gaussian weights, and
    the distance along the path (u = d . tangent)."""

    dx: np.ndarray
    dy: np.ndarray
    w: np.ndarray
    u: np.ndarray

    def rows(self, index: np.ndarray) -> _Offsets:
        return _Offsets(self.dx[index], self.dy[index], self.w[index], self.u[index])


def _offsets(at: np.ndarray, xy: np.ndarray, sigma_mm: float, tangent: np.ndarray) -> _Offsets:
    """The samples xy (M x 2) from the queries `at` (K x 2, unit tangents K x 2), weighted as local_planes."""
    dx = xy[None, :, 0] - at[:, None, 0]
    dy = xy[None, :, 1] - at[:, None, 1]
    w = np.exp(-(dx * dx + dy * dy) / (2.0 * sigma_mm**2))
    return _Offsets(dx, dy, w, dx * tangent[:, 0:1] + dy * tangent[:, 1:2])


def _slope_ridged(moments: np.ndarray, w: np.ndarray) -> np.ndarray:
    """A fit's normal matrix (K x P x P, terms 1 and 2 the gradient) with the ridge SLOPE_RIDGE_MM2 on the gradient,
    in units of each query's total weight (w: K x M)."""
    normal = moments.copy()
    ridge = SLOPE_RIDGE_MM2 * w.sum(axis=1)
    normal[:, 1, 1] += ridge
    normal[:, 2, 2] += ridge
    return normal


def _plane_and_cubic(
    seen: _Offsets, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Per query: the gradients (K x 2) and the rows of the linear estimators giving them (K x 2 x M) of two
    weighted fits, z = a + g . d and z = a + g . d + c2 u^2 + c3 u^3; the ridge SLOPE_RIDGE_MM2 on g. Also the
    cubic's moments for _knee: its terms' weighted cross sums (K x 5 x 5, unridged) and their sums with z (K x 5).
    Samples must be finite."""
    dx, dy, w, u = seen
    u2 = u * u
    basis = np.stack([np.ones_like(dx), dx, dy, u2, u2 * u], axis=1)  # K x 5 x M
    weighted = basis * w[:, None, :]
    moments = weighted @ basis.transpose(0, 2, 1)  # K x 5 x 5
    normal = _slope_ridged(moments, w)
    plane_rows = np.linalg.inv(normal[:, :3, :3])[:, 1:3] @ weighted[:, :3]  # K x 2 x M
    cubic_rows = np.linalg.inv(normal)[:, 1:3] @ weighted
    return plane_rows @ z, plane_rows, cubic_rows @ z, cubic_rows, (moments, weighted @ z)


def _quadratic(seen: _Offsets, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per query: the gradient (K x 2) and its estimator's rows (K x 2 x M) of the weighted fit
    z = a + g . d + d' H d / 2 (the offsets' Gaussian weights, the ridge SLOPE_RIDGE_MM2 on g)."""
    dx, dy, w, _ = seen
    basis = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=1)  # K x 6 x M
    weighted = basis * w[:, None, :]
    normal = _slope_ridged(weighted @ basis.transpose(0, 2, 1), w)
    rows = np.linalg.solve(normal, weighted)[:, 1:3]
    return rows @ z, rows


def _moment_fit(
    sums: np.ndarray, zsums: np.ndarray, zz: np.ndarray, total: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A weighted least-squares fit from its moments: per query the terms' weighted cross sums (K x P x P), their
    weighted sums with z (K x P), that of z^2 and of the weights (K). Returns the coefficients (K x P) and the
    weighted mean squared residual (K). The ridge SLOPE_RIDGE_MM2 on terms 1 and 2 (the gradient); the higher terms
    get 1e-9 (their squares run to 1e4-1e11 within a fit's reach): a knee whose curving side holds no sample has a
    term of zeros, which then fits as nothing instead of making the system singular."""
    normal = sums.copy()
    ridge = np.full(sums.shape[1], 1e-9)
    ridge[0], ridge[1:3] = 0.0, SLOPE_RIDGE_MM2
    # (and an absolute 1e-12 for a query with no sample within reach: it fits as nothing)
    normal += (ridge[None, :] * total[:, None] + 1e-12)[:, :, None] * np.eye(sums.shape[1])
    solution = np.linalg.solve(normal, zsums[..., None])[..., 0]
    # sum w (z - B b)^2 = sum w z^2 - 2 b . (B' W z) + b' (B' W B) b, with the unridged sums.
    residual = zz - 2.0 * np.sum(solution * zsums, axis=1) + np.einsum("kp,kpq,kq->k", solution, sums, solution)
    return solution, np.maximum(residual, 0.0) / np.maximum(total, 1e-300)


def _knee(
    seen: _Offsets, z: np.ndarray, tangent: np.ndarray, cubic_sums: np.ndarray, cubic_z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per query: the gradient (K x 2) of the best knee (KNEE_RSS_RATIO) and its weighted mean squared residual
    against the cubic's (K), with the cubic's weights and moments (_plane_and_cubic). The fits share the plane's
    moments; each knot adds five sums."""
    w = seen.w
    total, zz = w.sum(axis=1), w @ (z * z)
    _, cubic_residual = _moment_fit(cubic_sums, cubic_z, zz, total)
    queries = len(w)
    knot, side = _knee_knots()
    sums, zsums = _knee_moments(seen, z, knot, side)  # B x K x 4 (x 4): the bend's row, B = knots x sides
    full = np.zeros(sums.shape[:2] + (4, 4))
    full[..., :3, :3] = cubic_sums[None, :, :3, :3]
    full[..., 3, :], full[..., :, 3] = sums, sums
    zfull = np.concatenate([np.broadcast_to(cubic_z[None, :, :3], zsums.shape[:2] + (3,)), zsums[..., None]], axis=2)
    count, flat = len(sums), len(sums) * queries
    solution, residual = _moment_fit(
        full.reshape(flat, 4, 4), zfull.reshape(flat, 4), np.tile(zz, count), np.tile(total, count)
    )
    solution, residual = solution.reshape(count, queries, 4), residual.reshape(count, queries)
    # The slope at the query: the plane's, and the bend's where the query lies on its curving side.
    lever = (2.0 * side * np.clip(-side * knot, 0.0, None))[:, None]  # B x 1
    slopes = solution[..., 1:3] + tangent[None] * (lever * solution[..., 3])[..., None]
    fittest = np.argmin(residual, axis=0)
    best = residual[fittest, np.arange(queries)]
    gradient = slopes[fittest, np.arange(queries)]
    # A cubic that fits exactly (or no samples) leaves a knee nothing to explain.
    return gradient, np.where(cubic_residual > 0.0, best / np.maximum(cubic_residual, 1e-300), np.inf)


def _knee_knots() -> tuple[np.ndarray, np.ndarray]:
    """The knees' knots u0 (B) and sides s (B): every knot with s = +1, then every knot with s = -1."""
    knots = np.arange(-KNEE_KNOT_REACH_MM, KNEE_KNOT_REACH_MM + 1e-9, KNEE_KNOT_STEP_MM)
    return np.concatenate([knots, knots]), np.repeat([1.0, -1.0], len(knots))


def _knee_moments(seen: _Offsets, z: np.ndarray, knot: np.ndarray, side: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The knees' bend term b = ((s (u - u0))_+)^2 against the plane's terms and itself, sum w b (1, dx, dy, b)
    (B x K x 4), and sum w b z (B x K), for every knot u0 and side s (_knee_knots). b = (u - u0)^2 on the curving side,
    so each sum is a polynomial in u0 of the power sums sum w u^j (1, dx, dy, z) over the samples on that side: those
    are summed per interval between knots (a bincount per power) and accumulated from either end, instead of summing
    B x K x M products over every knot and side (26 times the arithmetic: 2-3 times the knee's time per pass)."""
    dx, dy, w, u = seen
    knots = knot[side > 0]
    rows = len(u)
    bins = len(knots) + 1
    # The interval of each sample: the number of knots below its u (a sample on a knot has a zero bend either side).
    interval = (np.searchsorted(knots, u) + bins * np.arange(rows)[:, None]).ravel()

    def per_bin(channel: np.ndarray) -> np.ndarray:  # K x M -> K x bins
        return np.bincount(interval, channel.ravel(), minlength=rows * bins).reshape(rows, bins)

    # Channels: w u^0..4, w dx u^0..2, w dy u^0..2, w z u^0..2; one at a time (a C x K x M stack is megabytes of
    # fresh pages per call, which cost more than the arithmetic).
    up = [w]
    for _ in range(4):
        up.append(up[-1] * u)
    per_bin_sums = np.stack(
        [per_bin(a) for a in up] + [per_bin(a * t) for t in (dx, dy, z[None, :]) for a in up[:3]]
    )  # C x K x bins
    above = np.cumsum(per_bin_sums[..., ::-1], axis=2)[..., ::-1][..., 1:]  # C x K x knots: u beyond knot i
    below = np.cumsum(per_bin_sums, axis=2)[..., :-1]  # u up to knot i
    power = np.concatenate([above, below], axis=2).transpose(0, 2, 1)  # C x B x K
    c = knot[:, None]

    def square(first: int) -> np.ndarray:  # sum w t (u - c)^2 from the power sums t u^0, t u^1, t u^2
        return power[first + 2] - 2.0 * c * power[first + 1] + c * c * power[first]

    fourth = power[4] - 4.0 * c * power[3] + 6.0 * c * c * power[2] - 4.0 * c**3 * power[1] + c**4 * power[0]
    return np.stack([square(0), square(5), square(8), fourth], axis=2), square(11)


def slope_gradients(
    at: np.ndarray,
    tangent: np.ndarray,
    xy: np.ndarray,
    z: np.ndarray,
    variance: np.ndarray,
    sigma_mm: float,
    spacing_mm: float,
    tip_sigma_mm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Surface gradient (K x 2) at points `at` of a closed path (unit tangents K x 2, samples `spacing_mm` apart):
    per point the plane or the plane with the slope's change along the path (see FOLD_TURN_DEG), whichever has
    the smaller expected error, and round a tip the quadratic of width `tip_sigma_mm` where it has the smaller
    expected error than the plane (TIP_TURN_DEG); where the cubic was taken, a knee if it fits far better
    (KNEE_RSS_RATIO). Samples xy (M x 2), heights z (M, NaN: left out) and each sample's noise
    variance (M, mm^2) counted with its correlation to its neighbours: a fit's variance is then taken as
    sum(row^2 x variance), which holds for rows that change little between correlated samples (a fit much
    wider than the correlation). Also returns where the cubic was taken (K bool).

    The along-path coordinate u means something only where the path does not fold back within the fit's reach
    (round a pointed end the projection of both sides onto one tangent mixes them and the cubic fits the fold):
    the cubic is used only where the path's tangent turns less than FOLD_TURN_DEG within 2 sigma either side.
    """
    finite = np.isfinite(z)
    xy, z = xy[finite], z[finite]
    known = known_variance(variance[finite])
    gradient, better = np.empty((len(at), 2)), unfolded(tangent, sigma_mm, spacing_mm)
    tip = round_a_tip(tangent, sigma_mm, spacing_mm)

    def fit_variance(rows: np.ndarray, noise: np.ndarray) -> np.ndarray:
        return np.sum(rows * rows * noise, axis=(1, 2))

    def lowers_the_error(fit: np.ndarray, rows: np.ndarray, plane: np.ndarray, plane_rows: np.ndarray) -> np.ndarray:
        # The plane's bias squared (the squared difference less its noise variance) and its own variance against
        # the fit's variance: the fit where that is the smaller expected error.
        difference_var = fit_variance(rows - plane_rows, noise)
        return np.sum((fit - plane) ** 2, axis=1) - difference_var + fit_variance(plane_rows, noise) > fit_variance(
            rows, noise
        )

    for part in query_chunks(len(at)):
        near = within_reach(at[part], xy, max(sigma_mm, tip_sigma_mm) if tip[part].any() else sigma_mm)
        seen = _offsets(at[part], xy[near], sigma_mm, tangent[part])
        plane, plane_rows, cubic, cubic_rows, (cubic_sums, cubic_z) = _plane_and_cubic(seen, z[near])
        noise = known[near]
        better[part] &= lowers_the_error(cubic, cubic_rows, plane, plane_rows)
        gradient[part] = np.where(better[part, None], cubic, plane)
        if tip[part].any():
            rounding = np.flatnonzero(tip[part])
            wide = _offsets(at[part][rounding], xy[near], tip_sigma_mm, tangent[part][rounding])
            quadratic, quadratic_rows = _quadratic(wide, z[near])
            taken = lowers_the_error(quadratic, quadratic_rows, plane[rounding], plane_rows[rounding])
            gradient[part][rounding[taken]] = quadratic[taken]
        if better[part].any():
            curving = np.flatnonzero(better[part])
            knee, ratio = _knee(
                seen.rows(curving), z[near], tangent[part][curving], cubic_sums[curving], cubic_z[curving]
            )
            gradient[part][curving[ratio < KNEE_RSS_RATIO]] = knee[ratio < KNEE_RSS_RATIO]
    return gradient, better


def within_reach(at: np.ndarray, xy: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Indices of the samples xy (M x 2) a pass of fits of width `sigma_mm` at the queries `at` reads: those in the
    queries' bounding box grown by FIT_REACH_SIGMAS widths (every sample that near a query, and a few more)."""
    reach = FIT_REACH_SIGMAS * sigma_mm
    low, high = at.min(axis=0) - reach, at.max(axis=0) + reach
    return np.flatnonzero(np.all((xy >= low) & (xy <= high), axis=1))


def query_chunks(count: int) -> list[slice]:
    """The queries 0..count-1 in passes of QUERY_CHUNK."""
    return [slice(start, min(start + QUERY_CHUNK, count)) for start in range(0, count, QUERY_CHUNK)]
