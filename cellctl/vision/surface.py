"""The sole's top surface at given table points: height and normal, as precisely as the data allows.

With the rectified images at hand (a stereo reconstruction), each query is a small patch of the surface
whose disparity plane is fitted directly to the images (cellctl.vision.subpixel), then reprojected and turned
into a plane in the table frame. Without images (a cloud from elsewhere, e.g. the simulator's true depth)
the same plane is fitted to the cloud's points near the query.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent import futures
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from cellctl.stereo.pointgrid import PointGrid
from cellctl.vision.local_fit import (
    GRADIENT_RIDGE_MM2,
    known_variance,
    query_chunks,
    unfolded,
    upward_normals,
    within_reach,
)
from cellctl.vision.reconstruction import Reconstruction
from cellctl.vision.subpixel import refine_patches
from cellctl.vision.workers import worker

MIN_CLOUD_POINTS = 12
MAX_REFINE_SHIFT_MM = 3.0  # an image fit never moves a height this far from the cloud's median (~1 px disparity)
TRIM = 0.2  # fraction of points dropped at each end of the height distribution in the cloud fallback
GRID_CELL_MM = 2.0  # the neighbour grid's cells: a 4 mm query reads 5 x 5 of them

T = TypeVar("T")


@dataclass
class SurfaceSamples:
    """Heights (mm above the table) and unit normals at the queried table points; NaN where not measured."""

    z: np.ndarray  # K
    normals: np.ndarray  # K x 3
    refined: np.ndarray  # K bool: fitted on the images (else on the cloud)


class SoleSurface:
    """Queries of a reconstructed sole's top surface."""

    def __init__(self, reconstruction: Reconstruction) -> None:
        self.rec = reconstruction
        points = reconstruction.sole_points
        # Neighbours in the table plane, a cell grid searched in C (cellctl.stereo.pointgrid.PointGrid: the
        # neighbours and order a k-d tree's radius search gives, without a Python call per query); built here
        # (~10^5 points, a few ms), so that threads may query it at once.
        self.grid = PointGrid(points[:, :2], GRID_CELL_MM, points[:, 2])

    def sample(self, xy: np.ndarray, radius_mm: float, parallel: bool = False) -> SurfaceSamples:
        """Surface height and normal at table points xy (K x 2), from a patch of `radius_mm` around each.

        parallel: the cloud's medians and the image fits of half the queries each on two threads (the same
        result: every query's median and patch is its own, fitted with the patch radius of all the queries)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        refined = np.zeros(len(xy), bool)
        if self.rec.rectified is None:
            z, normals = self.cloud_planes(xy, radius_mm)
            return SurfaceSamples(z, normals, refined)
        half = len(xy) // 2
        parts = (np.arange(half), np.arange(half, len(xy))) if parallel and half > 0 else (np.arange(len(xy)),)
        z = np.concatenate(_on_threads(lambda part: self.coarse_heights(xy[part], radius_mm), parts))
        normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        if np.any(np.isfinite(z)):
            self._refine(xy, z, normals, refined, radius_mm, parallel)
        # Where the images gave no fit (too few pixels, no convergence), fall back to the cloud.
        rest = np.flatnonzero(~refined)
        if rest.size:
            z[rest], normals[rest] = self.cloud_planes(xy[rest], radius_mm)
        return SurfaceSamples(z, normals, refined)

    def coarse_heights(self, xy: np.ndarray, radius_mm: float) -> np.ndarray:
        """Median height of the cloud's points within the radius (NaN where too few): the refinement's start."""
        counts, medians = self.grid.radius_medians(xy, radius_mm)
        return np.where(counts >= MIN_CLOUD_POINTS, medians, np.nan)

    def cloud_planes(self, xy: np.ndarray, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Height and unit normal at table points xy (K x 2) of a plane through the cloud's points within the radius
        (trimmed of the highest and lowest residuals, `robust_planes`); NaN height and an upright normal where too
        few points."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        z = np.full(len(xy), np.nan)
        normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        counts, members = self.grid.radius_members(xy, radius_mm)
        enough = np.flatnonzero(counts >= MIN_CLOUD_POINTS)
        if enough.size:
            query = np.repeat(np.arange(len(xy)), counts)
            chosen = np.flatnonzero(counts[query] >= MIN_CLOUD_POINTS)
            ids = np.searchsorted(enough, query[chosen])  # 0..len(enough)-1, ascending
            z[enough], normals[enough] = robust_planes(
                np.take(self.rec.sole_points, members[chosen], axis=0), xy[enough], ids
            )
        return z, normals

    def _refine(
        self,
        xy: np.ndarray,
        z: np.ndarray,
        normals: np.ndarray,
        refined: np.ndarray,
        radius_mm: float,
        parallel: bool = False,
    ) -> None:
        rec = self.rec
        calib, to_table, mask = rec.calibration, rec.camera_to_table, rec.sole_mask
        rectified = rec.rectified if rec.surface_grey is None else rec.surface_grey
        if calib is None or rectified is None or to_table is None or mask is None:
            return  # not a stereo reconstruction: the cloud answers every query
        left, right = rectified
        table_to_camera = np.linalg.inv(to_table)
        known = np.flatnonzero(np.isfinite(z))
        guess = np.column_stack([xy[known], z[known]]) @ table_to_camera[:3, :3].T + table_to_camera[:3, 3]
        focal = calib.focal_px
        centres = guess[:, :2] / guess[:, 2:3] * focal + calib.P1[:2, 2]
        start = focal * calib.baseline_mm / guess[:, 2]
        radius_px = radius_mm * focal / float(np.median(guess[:, 2]))

        def fit(part: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            """Image fits of the known queries `part`: which succeeded, their heights and normals."""
            patches = refine_patches(left, right, mask, centres[part], radius_px, start[part])
            planes = table_planes(patches.params, centres[part], calib.Q, table_to_camera)
            patch_z, patch_normals = heights_on_planes(planes, xy[known[part]])
            # A fit that moved the height far from the cloud's own (a highlight, a mismatch) failed: the
            # cloud's plane takes over there.
            done = patches.ok & np.isfinite(patch_z) & (np.abs(patch_z - z[known[part]]) < MAX_REFINE_SHIFT_MM)
            return part[done], patch_z[done], patch_normals[done]

        # parallel: the patches of the upper and the lower half of the image rows on two threads (numpy, OpenCV
        # and the C kernels release the GIL), so that each thread filters only the rows of its own patches
        # (subpixel.fit_disparity_planes). Every query is fitted on its own with the radius of all of them: the
        # same result.
        half = len(known) // 2
        if parallel and half > 0:
            by_row = np.argsort(centres[:, 1], kind="stable")
            parts: tuple[np.ndarray, ...] = (np.sort(by_row[:half]), np.sort(by_row[half:]))
        else:
            parts = (np.arange(len(known)),)
        for part, part_z, part_normals in _on_threads(fit, parts):
            z[known[part]], normals[known[part]], refined[known[part]] = part_z, part_normals, True


def _on_threads(function: Callable[[np.ndarray], T], parts: tuple[np.ndarray, ...]) -> list[T]:
    """function(part) for each of one or two parts, the second on a worker thread beside the first."""
    if len(parts) == 1:
        return [function(parts[0])]
    second = worker("patch-fits").submit(function, parts[1])
    try:
        first = function(parts[0])
    finally:
        futures.wait([second])
    return [first, second.result()]


def table_planes(params: np.ndarray, centres: np.ndarray, Q: np.ndarray, table_to_camera: np.ndarray) -> np.ndarray:
    """The table-frame planes (K x 4, p . (x, y, z, 1) = 0) of patches' affine disparities (params K x 3: a, b, c
    about `centres` K x 2, cellctl.vision.subpixel.PatchFit), through the reprojection Q and the table's pose.

    A plane in (x, y, disparity) stays a plane through the projective reprojection and the rigid move to the
    table, so every pixel of a patch lands on this plane: it is the plane a least-squares fit to the patch's
    reprojected pixels finds, in a few products per patch instead of a reprojection and a fit over its ~150
    pixels (~20 ms of a cycle's glue path; issue 11, session 16)."""
    a, b, c = params.T
    image = np.column_stack([b, c, -np.ones(len(a)), a - b * centres[:, 0] - c * centres[:, 1]])
    return image @ np.linalg.inv(Q) @ table_to_camera


def heights_on_planes(planes: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heights (K) above the table points xy (K x 2) on table-frame planes (K x 4, table_planes) and the planes'
    unit normals (K x 3, pointing up); NaN for a plane that stands upright."""
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = -planes[:, :3] / planes[:, 2:3]  # (gx, gy, -1): the plane z = gx x + gy y + z0
        z = slope[:, 0] * xy[:, 0] + slope[:, 1] * xy[:, 1] - planes[:, 3] / planes[:, 2]
    normals = upward_normals(slope[:, :2])
    finite = np.isfinite(z) & np.all(np.isfinite(normals), axis=1)
    return np.where(finite, z, np.nan), normals


def robust_planes(points: np.ndarray, at: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per query (at, K x 2) the plane z = z0 + gx (x - x0) + gy (y - y0) through its points (points N x 3, query
    ids N, ascending, every query with 3 or more), fitted again after dropping the points whose residuals lie
    below the TRIM or above the 1 - TRIM quantile of the query's (numpy's linear quantiles): z0 and the unit
    normal per query. All queries at once on segmented sums (the depth's normals of a whole glue path are
    hundreds of queries: 0.3-0.8 ms each, fitted one by one in Python)."""
    count = len(at)
    dx = points[:, 0] - at[ids, 0]
    dy = points[:, 1] - at[ids, 1]
    coef = _segment_planes(dx, dy, points[:, 2], ids, count, np.ones(len(ids), bool))
    residual = points[:, 2] - (coef[ids, 0] + coef[ids, 1] * dx + coef[ids, 2] * dy)
    low, high = _segment_quantiles(residual, ids, count, (TRIM, 1.0 - TRIM))
    keep = (residual >= low[ids]) & (residual <= high[ids])
    refit = np.bincount(ids, weights=keep, minlength=count) >= 3
    coef = np.where(refit[:, None], _segment_planes(dx, dy, points[:, 2], ids, count, keep), coef)
    return coef[:, 0], upward_normals(coef[:, 1:3])


def _segment_planes(
    dx: np.ndarray, dy: np.ndarray, z: np.ndarray, ids: np.ndarray, count: int, use: np.ndarray
) -> np.ndarray:
    """Least-squares (z0, gx, gy) per query over its points where `use` (K x 3): the normal equations, solved by
    the pseudo-inverse (the least-norm solution, as np.linalg.lstsq gives, where the points are degenerate)."""
    w = use.astype(np.float64)
    wx, wy = w * dx, w * dy
    terms = np.stack((w, wx, wy, wx * dx, wx * dy, wy * dy, w * z, wx * z, wy * z))
    # One reduceat over the rows of all nine terms (ids ascending, no query empty): ~3 x faster than nine bincounts.
    s1, sx, sy, sxx, sxy, syy, sz, sxz, syz = np.add.reduceat(terms, _segments(ids, count)[1], axis=1)
    normal = np.stack([np.stack([s1, sx, sy], -1), np.stack([sx, sxx, sxy], -1), np.stack([sy, sxy, syy], -1)], -2)
    rhs = np.stack([sz, sxz, syz], -1)
    return np.einsum("kij,kj->ki", np.linalg.pinv(normal), rhs)


def _segments(ids: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """How many values each query has in `ids` (ascending, every query 0..count-1 present) and where they start."""
    sizes = np.bincount(ids, minlength=count)
    return sizes, np.cumsum(sizes) - sizes


def _segment_quantiles(
    values: np.ndarray, ids: np.ndarray, count: int, quantiles: tuple[float, ...]
) -> tuple[np.ndarray, ...]:
    """Per query the `quantiles` of its values (ids ascending, every query with at least one value), interpolated
    linearly between order statistics as np.quantile's default does."""
    sizes, starts = _segments(ids, count)
    # Each query's values in a row of their own, padded with +inf, sorted along the rows: the order statistics by
    # (row, rank). A lexsort of (values, ids) over all of them took ~5 x as long.
    table = np.full((count, int(sizes.max())), np.inf)
    table[ids, np.arange(len(ids)) - starts[ids]] = values
    table.sort(axis=1)
    rows = np.arange(count)
    result = []
    for q in quantiles:
        position = (sizes - 1) * q
        below = np.floor(position).astype(np.int64)
        above = np.minimum(below + 1, sizes - 1)
        t = position - below
        a, b = table[rows, below], table[rows, above]
        # numpy's lerp: from the nearer end, so that a whole position gives the order statistic itself.
        result.append(np.where(t >= 0.5, b - (b - a) * (1.0 - t), a + (b - a) * t))
    return tuple(result)


# Heights along a closed path (the glue path) from its patches' noisy heights: a local fit along the path, of a
# width and shape chosen per point for the smallest expected error. The patches' heights scatter ~0.15 mm on light
# soles and ~0.35 mm on black rubber (the matcher's noise on weak texture, correlated over a few mm): a wide fit
# averages it, but a plane wider than a curved top bends (a plane of 12 mm put two light matrix soles' glue
# heights 1.0 mm off that 6 mm kept within 0.5; on black soles the old rule's noise-driven 12 mm put 2001's worst
# point 0.69 mm high by the fit alone, where 6 mm costs 0.24). The candidates are planes at each width of
# PATH_SMOOTHING_STEPS_MM and the plane plus the height's curve along the path (u^2, u the distance along the
# tangent) at the widest;
# each candidate's expected squared error is its noise variance (the samples' own, propagated exactly through its
# linear rows) plus its squared bias, estimated as the squared difference from the least biased candidate less
# that difference's noise variance (path_heights).
PATH_SMOOTHING_MM = 6.0
PATH_SMOOTHING_STEPS_MM = (6.0, 8.0, 10.0, 12.0)  # candidate widths (Gaussian sigma of the fits' weights)
PATH_NOISE_LAG = 2  # samples: the noise from second differences at this lag (a smooth top's curve drops out)
PATH_NOISE_WINDOW = 8  # samples either side over which the local noise is taken
# Where the path turns sharply (round a pointed or cusped end) a second difference spans both sides of the tip, and
# on a top that rises to it (a sprung toe) it reads the kink of the heights along the path, not their noise: at a
# sprung pointed toe (0.5 slope along the path) ~1.6 mm at the tip's sample, which put the tip's expected glue-height
# errors at 0.6-0.9 mm where the heights were 0.3-0.7 mm off (error / expected 0.42-1.24; 8 of 12 such soles refused
# for glue precision, all 10 that reached their glue path right with the check off). A round end turns ~15 degrees
# over the 2 x 4 mm of the chords (a 30 mm radius); a pointed tip 120-150.
PATH_NOISE_MAX_TURN_DEG = 45.0


def path_noise(
    z: np.ndarray, lag: int = PATH_NOISE_LAG, window: int = PATH_NOISE_WINDOW, xy: np.ndarray | None = None
) -> np.ndarray:
    """Local noise (RMS, mm) of heights sampled along a closed path: second differences at `lag` samples,
    scaled to a single sample's scatter, over `window` samples either side; NaN where none is known. With the
    samples' table points `xy`, the second differences where the path turns by more than PATH_NOISE_MAX_TURN_DEG
    between them are left out (`sharp_turns`)."""
    second = (z - 0.5 * (np.roll(z, lag) + np.roll(z, -lag))) / np.sqrt(1.5)
    if xy is not None:
        second = np.where(sharp_turns(xy, lag), np.nan, second)
    n = len(z)
    index = (np.arange(n)[:, None] + np.arange(-window, window + 1)[None]) % n
    squares = second[index] ** 2
    known = np.isfinite(squares)
    count = known.sum(axis=1)
    total = np.where(known, squares, 0.0).sum(axis=1)
    return np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.nan)


def sharp_turns(xy: np.ndarray, lag: int = PATH_NOISE_LAG) -> np.ndarray:
    """Per sample of a closed path (K x 2): whether the chords to the samples `lag` before and after it turn by more
    than PATH_NOISE_MAX_TURN_DEG."""
    back, ahead = xy - np.roll(xy, lag, axis=0), np.roll(xy, -lag, axis=0) - xy
    lengths = np.linalg.norm(back, axis=1) * np.linalg.norm(ahead, axis=1)
    cosine = np.sum(back * ahead, axis=1) / np.maximum(lengths, 1e-12)
    return cosine < np.cos(np.radians(PATH_NOISE_MAX_TURN_DEG))


@dataclass(frozen=True)
class RingSamples:
    """Patch heights off the path (rings further inside the sole): table points (M x 2), heights (M, NaN:
    unknown) and their noise variances counted like path_heights' `variance`."""

    xy: np.ndarray
    z: np.ndarray
    variance: np.ndarray


def path_heights(
    xy: np.ndarray, z: np.ndarray, variance: np.ndarray, ring: RingSamples | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Heights at the samples (xy K x 2, heights z K, NaN: unknown) of a closed path, each from the local fit of
    smallest expected error (see PATH_SMOOTHING_STEPS_MM), and that expected error (K, mm, an sd: the fit's noise
    and its estimated bias): `variance` (K, mm^2) is each sample's noise variance counted with its correlation to
    its neighbours (glue_path.sample_variance), so that a fit's variance is sum(row^2 x variance)
    (local_fit.slope_gradients).

    The reference for the bias is the plane plus the curve along the path at the widest width: no bias from the
    top's curve along the path and the least noise of such fits. Where the path turns more than
    local_fit.FOLD_TURN_DEG within that fit's reach (round a pointed end) the distance along one tangent means
    nothing: there only planes compete and the narrowest is the reference.

    With a `ring` of samples further inside, planes over the path's and the ring's samples together compete too
    (glue_path.GLUE_HEIGHT_RING_MM says why), judged against the same reference."""
    result, expected = np.full(len(z), np.nan), np.full(len(z), np.nan)
    finite = np.isfinite(z)
    if not finite.any():
        return result, expected
    known = known_variance(variance)
    tangent = np.roll(xy, -1, axis=0) - np.roll(xy, 1, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    path_xy, samples, noise = xy[finite], z[finite], known[finite]
    ring_xy, ring_z, ring_noise = np.empty((0, 2)), np.empty(0), np.empty(0)
    if ring is not None:
        inside = np.isfinite(ring.z)
        ring_xy, ring_z, ring_noise = ring.xy[inside], ring.z[inside], known_variance(ring.variance)[inside]
    widest = PATH_SMOOTHING_STEPS_MM[-1]
    straight = unfolded(tangent, widest, _median_spacing(xy))
    for part in query_chunks(len(z)):  # a few queries at a time, over the samples within reach (local_fit)
        near, near_ring = within_reach(xy[part], path_xy, widest), within_reach(xy[part], ring_xy, widest)
        if not near.size:
            continue  # no height known within reach: these stay unknown
        across = None
        if near_ring.size:
            both = np.vstack([path_xy[near], ring_xy[near_ring]])
            across = (
                _RowGeometry(xy[part], both, None),
                np.concatenate([samples[near], ring_z[near_ring]]),
                np.concatenate([noise[near], ring_noise[near_ring]]),
            )
        result[part], expected[part] = _least_error_heights(
            _RowGeometry(xy[part], path_xy[near], tangent[part]), samples[near], noise[near], straight[part], across
        )
    return result, np.sqrt(expected)


def _least_error_heights(
    geometry: _RowGeometry,
    samples: np.ndarray,
    noise: np.ndarray,
    straight: np.ndarray,
    across: tuple[_RowGeometry, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """path_heights at the queries of `geometry` (whose fits along the path are unfolded where `straight`), and
    their expected squared errors; `across`: the geometry, heights and noise of the path's samples followed by a
    ring's, for the planes over both."""
    # The planes narrow to wide, then the curved fit at the widest width: the reference where the path is straight.
    # A narrower curved fit cannot win there but by a rounding: its expected error is at least its variance, which
    # exceeds the reference's own (the fit of the same shape over more samples). Over the 135 valid results of the
    # matrix sets 2000-4000 none was chosen, so it is not computed (issue 11, session 10, glue10).
    rows = [geometry.rows(width, False) for width in PATH_SMOOTHING_STEPS_MM]
    rows.append(geometry.rows(PATH_SMOOTHING_STEPS_MM[-1], True))
    estimates = np.array([r @ samples for r in rows])
    variances = np.array([(r * r) @ noise for r in rows])
    planes = len(PATH_SMOOTHING_STEPS_MM)
    reference = np.where(straight[:, None], rows[-1], rows[0])
    reference_estimate = np.where(straight, estimates[-1], estimates[0])
    error = np.empty_like(estimates)
    for i, r in enumerate(rows):
        difference = r - reference
        difference *= difference
        error[i] = np.maximum((estimates[i] - reference_estimate) ** 2 - difference @ noise, 0.0) + variances[i]
    error[planes:, ~straight] = np.inf
    if across is not None:
        estimates, error = _with_ring_planes(estimates, error, reference, reference_estimate, across)
    best = np.argmin(error, axis=0)
    pick = np.arange(len(straight))
    return estimates[best, pick], error[best, pick]


def _with_ring_planes(
    estimates: np.ndarray,
    error: np.ndarray,
    reference: np.ndarray,
    reference_estimate: np.ndarray,
    across: tuple[_RowGeometry, np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates' estimates and expected squared errors with the planes over the path and the ring added at
    each width, their bias judged against the path's own reference fit (whose rows `reference` weigh the path's
    samples, the first of `across`'s)."""
    geometry, samples, noise = across
    path_count = reference.shape[1]
    ring_estimates, ring_errors = [], []
    for width in PATH_SMOOTHING_STEPS_MM:
        rows = geometry.rows(width, False)
        difference = rows.copy()
        difference[:, :path_count] -= reference
        estimate = rows @ samples
        bias = np.maximum((estimate - reference_estimate) ** 2 - (difference * difference) @ noise, 0.0)
        ring_estimates.append(estimate)
        ring_errors.append(bias + (rows * rows) @ noise)
    return np.vstack([estimates, *ring_estimates]), np.vstack([error, *ring_errors])


def height_rows(at: np.ndarray, xy: np.ndarray, sigma_mm: float, tangent: np.ndarray | None = None) -> np.ndarray:
    """Rows (K x M) of the linear estimators of the height at points `at` (K x 2) from samples at xy (M x 2): the
    plane of local_fit.local_planes (same weights and ridge), plus the curve along `tangent` (K x 2, unit; u^2, u
    the distance along it) when given."""
    return _RowGeometry(at, xy, tangent).rows(sigma_mm, tangent is not None)


class _RowGeometry:
    """The offsets of the samples from each query, shared by the fits of every width."""

    def __init__(self, at: np.ndarray, xy: np.ndarray, tangent: np.ndarray | None) -> None:
        self.dx = xy[None, :, 0] - at[:, None, 0]
        self.dy = xy[None, :, 1] - at[:, None, 1]
        # the weighted sums' terms: the plane's, then the curve's (u^2 and its products)
        terms = [self.dx, self.dy, self.dx * self.dx, self.dx * self.dy, self.dy * self.dy]
        self.squared = terms[2] + terms[4]
        self.u2 = None
        if tangent is not None:
            u = self.dx * tangent[:, 0:1] + self.dy * tangent[:, 1:2]
            self.u2 = u * u
            terms += [self.u2, self.dx * self.u2, self.dy * self.u2, self.u2 * self.u2]
        self.terms = terms
        # Per width: the weights, their sums and the weighted sums of the terms so far (the plane's and the
        # curved fit's of one width share the weights and the plane's sums).
        self._sums: dict[float, tuple[np.ndarray, np.ndarray, list[np.ndarray]]] = {}

    def rows(self, sigma_mm: float, curved: bool) -> np.ndarray:
        count = 9 if curved else 5
        if sigma_mm not in self._sums:
            w = np.exp(self.squared / (-2.0 * sigma_mm**2))
            self._sums[sigma_mm] = (w, w.sum(axis=1), [])
        w, s, m = self._sums[sigma_mm]
        m += [np.einsum("km,km->k", w, term) for term in self.terms[len(m) : count]]
        ridge = GRADIENT_RIDGE_MM2 * s
        size = 4 if curved else 3
        normal = np.empty((len(s), size, size))
        normal[:, 0, 0] = s
        normal[:, 0, 1] = normal[:, 1, 0] = m[0]
        normal[:, 0, 2] = normal[:, 2, 0] = m[1]
        normal[:, 1, 1] = m[2] + ridge
        normal[:, 1, 2] = normal[:, 2, 1] = m[3]
        normal[:, 2, 2] = m[4] + ridge
        if curved:
            normal[:, 0, 3] = normal[:, 3, 0] = m[5]
            normal[:, 1, 3] = normal[:, 3, 1] = m[6]
            normal[:, 2, 3] = normal[:, 3, 2] = m[7]
            normal[:, 3, 3] = m[8]
        unit = np.zeros((len(s), size, 1))
        unit[:, 0, 0] = 1.0
        c = np.linalg.solve(normal, unit)[..., 0]  # the height's row of the inverse (normal is symmetric)
        combination = c[:, 0:1] + c[:, 1:2] * self.dx + c[:, 2:3] * self.dy
        if curved:
            assert self.u2 is not None
            combination += c[:, 3:4] * self.u2
        combination *= w
        return combination


def _median_spacing(xy: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(np.diff(xy, axis=0), axis=1))) if len(xy) > 1 else 1.0
