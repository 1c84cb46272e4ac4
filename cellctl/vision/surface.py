"""The sole's top surface at given table points: height and normal, as precisely as the data allows.

With the rectified images at hand (a stereo reconstruction), each query is a small patch of the surface
whose disparity plane is fitted directly to the images (cellctl.vision.subpixel), then reprojected and turned
into a plane in the table frame. Without images (a cloud from elsewhere, e.g. the simulator's true depth)
the same plane is fitted to the cloud's points near the query.
"""

from __future__ import annotations

from concurrent import futures
from dataclasses import dataclass

import numpy as np

from cellctl.stereo.pointgrid import PointGrid
from cellctl.vision.local_fit import local_planes
from cellctl.vision.reconstruction import Reconstruction
from cellctl.vision.subpixel import PatchSums, refine_patches
from cellctl.vision.workers import worker

MIN_CLOUD_POINTS = 12
MAX_REFINE_SHIFT_MM = 3.0  # an image fit never moves a height this far from the cloud's median (~1 px disparity)
TRIM = 0.2  # fraction of points dropped at each end of the height distribution in the cloud fallback
GRID_CELL_MM = 2.0  # the neighbour grid's cells: a 4 mm query reads 5 x 5 of them


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

        parallel: the image fits of the first and second half of the queries on two threads (the same
        result: every patch is fitted on its own, with the patch radius of all the queries)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        refined = np.zeros(len(xy), bool)
        if self.rec.rectified is None:
            z, normals = self._from_cloud(xy, radius_mm)
            return SurfaceSamples(z, normals, refined)
        z = self.coarse_heights(xy, radius_mm)
        normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        if np.any(np.isfinite(z)):
            self._refine(xy, z, normals, refined, radius_mm, parallel)
        # Where the images gave no fit (too few pixels, no convergence), fall back to the cloud.
        rest = np.flatnonzero(~refined)
        if rest.size:
            z[rest], normals[rest] = self._from_cloud(xy[rest], radius_mm)
        return SurfaceSamples(z, normals, refined)

    def coarse_heights(self, xy: np.ndarray, radius_mm: float) -> np.ndarray:
        """Median height of the cloud's points within the radius (NaN where too few): the refinement's start."""
        counts, medians = self.grid.radius_medians(xy, radius_mm)
        return np.where(counts >= MIN_CLOUD_POINTS, medians, np.nan)

    def _from_cloud(self, xy: np.ndarray, radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
        points = self.rec.sole_points
        z = np.full(len(xy), np.nan)
        normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        for k, (index, (x, y)) in enumerate(zip(self.grid.radius_indices(xy, radius_mm), xy, strict=True)):
            if len(index) < MIN_CLOUD_POINTS:
                continue
            z[k], normals[k] = _robust_plane(points[index], np.array([x, y]))
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
        calib, rectified, to_table, mask = rec.calibration, rec.rectified, rec.camera_to_table, rec.sole_mask
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
            pixel_disparity = np.column_stack(
                [patches.xy, patches.disparities(centres[part]), np.ones(len(patches.ids))]
            )
            homogeneous = pixel_disparity @ calib.Q.T
            camera = homogeneous[:, :3] / homogeneous[:, 3:4]
            table = camera @ to_table[:3, :3].T + to_table[:3, 3]
            patch_z, patch_normals = _planes_at(table, patches.ids, xy[known[part]])
            # A fit that moved the height far from the cloud's own (a highlight, a mismatch) failed: the
            # cloud's plane takes over there.
            done = patches.ok & np.isfinite(patch_z) & (np.abs(patch_z - z[known[part]]) < MAX_REFINE_SHIFT_MM)
            return part[done], patch_z[done], patch_normals[done]

        # parallel: the second half of the queries on a worker thread (numpy, OpenCV and the C kernels release
        # the GIL). Every query is fitted on its own with the radius of all of them: the same result.
        half = len(known) // 2
        if parallel and half > 0:
            second = worker("patch-fits").submit(fit, np.arange(half, len(known)))
            try:
                results = [fit(np.arange(half))]
            finally:
                futures.wait([second])
            results.append(second.result())
        else:
            results = [fit(np.arange(len(known)))]
        for part, part_z, part_normals in results:
            z[known[part]], normals[known[part]], refined[known[part]] = part_z, part_normals, True


def _planes_at(points: np.ndarray, ids: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """_plane_at for many patches at once: points (N x 3) of patch ids (sorted), evaluated at xy (K x 2).

    Least squares by per-patch normal equations (sums of products), all patches in one pass.
    """
    u, v = (points[:, :2] - xy[ids]).T
    w = points[:, 2]
    moments = PatchSums(ids, len(xy))(np.vstack([np.ones_like(u), u, v, u * u, u * v, v * v, w, w * u, w * v]))
    s1, su, sv, suu, suv, svv, sw, swu, swv = moments
    normal = np.stack([np.stack(row, -1) for row in ((s1, su, sv), (su, suu, suv), (sv, suv, svv))], -2)
    rhs = np.stack([sw, swu, swv], -1)
    solvable = np.abs(np.linalg.det(normal)) > 1e-9 * np.maximum(s1, 1.0) ** 3
    coef = np.full((len(xy), 3), np.nan)
    coef[solvable] = np.linalg.solve(normal[solvable], rhs[solvable][..., None])[..., 0]
    normals = np.column_stack([-coef[:, 1], -coef[:, 2], np.ones(len(xy))])
    return coef[:, 0], normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _plane_at(points: np.ndarray, xy: np.ndarray) -> tuple[float, np.ndarray]:
    """Least-squares plane z = z0 + gx (x - x0) + gy (y - y0) through points: z0 and the unit normal."""
    design = np.column_stack([np.ones(len(points)), points[:, 0] - xy[0], points[:, 1] - xy[1]])
    coef = np.linalg.lstsq(design, points[:, 2], rcond=None)[0]
    normal = np.array([-coef[1], -coef[2], 1.0])
    return float(coef[0]), normal / np.linalg.norm(normal)


def _robust_plane(points: np.ndarray, xy: np.ndarray) -> tuple[float, np.ndarray]:
    """Plane through the points after trimming the highest and lowest TRIM of their residuals."""
    z0, normal = _plane_at(points, xy)
    predicted = z0 - ((points[:, 0] - xy[0]) * normal[0] + (points[:, 1] - xy[1]) * normal[1]) / normal[2]
    residual = points[:, 2] - predicted
    lo, hi = np.quantile(residual, [TRIM, 1.0 - TRIM])
    keep = (residual >= lo) & (residual <= hi)
    if keep.sum() >= 3:
        z0, normal = _plane_at(points[keep], xy)
    return z0, normal


# Heights along a closed path (the glue path) from its patches' noisy heights: a local plane fit whose width
# grows with the local noise, so that its error stays about the same. The patches' heights scatter ~0.15 mm
# on light soles and ~0.35 mm on black rubber (the matcher's noise on weak texture, correlated over a few mm);
# a fit of width w averages it by ~1 / sqrt(w), so the width goes with the noise squared: PATH_SMOOTHING_MM at
# PATH_NOISE_REF_MM and below, up to PATH_SMOOTHING_MAX_MM. Wider costs accuracy where the top is curved
# (a fixed 12 mm put two light matrix soles' glue heights 1.0 mm off that 6 mm kept within 0.5).
PATH_SMOOTHING_MM = 6.0
PATH_SMOOTHING_MAX_MM = 12.0
PATH_SMOOTHING_STEPS_MM = (6.0, 8.0, 10.0, 12.0)  # fits made; a width between two is interpolated
PATH_NOISE_REF_MM = 0.2
PATH_NOISE_LAG = 2  # samples: the noise from second differences at this lag (a smooth top's curve drops out)
PATH_NOISE_WINDOW = 8  # samples either side over which the local noise is taken


def path_noise(z: np.ndarray, lag: int = PATH_NOISE_LAG, window: int = PATH_NOISE_WINDOW) -> np.ndarray:
    """Local noise (RMS, mm) of heights sampled along a closed path: second differences at `lag` samples,
    scaled to a single sample's scatter, over `window` samples either side; NaN where none is known."""
    second = (z - 0.5 * (np.roll(z, lag) + np.roll(z, -lag))) / np.sqrt(1.5)
    n = len(z)
    index = (np.arange(n)[:, None] + np.arange(-window, window + 1)[None]) % n
    squares = second[index] ** 2
    known = np.isfinite(squares)
    count = known.sum(axis=1)
    total = np.where(known, squares, 0.0).sum(axis=1)
    return np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.nan)


def path_smoothing_widths(z: np.ndarray) -> np.ndarray:
    """Per sample of a closed path: the local plane fit's width for its heights (see PATH_SMOOTHING_MM)."""
    noise = np.nan_to_num(path_noise(z), nan=0.0)
    return np.clip(PATH_SMOOTHING_MM * (noise / PATH_NOISE_REF_MM) ** 2, PATH_SMOOTHING_MM, PATH_SMOOTHING_MAX_MM)


def path_heights(xy: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Heights at the samples (xy K x 2, heights z K, NaN: unknown) of a closed path, from local plane fits
    (cellctl.vision.local_fit) of a width that grows with the local noise (`path_smoothing_widths`)."""
    widths = path_smoothing_widths(z)
    steps = np.asarray(PATH_SMOOTHING_STEPS_MM)
    upper = np.clip(np.searchsorted(steps, widths), 1, len(steps) - 1)
    lower = upper - 1
    share = (widths - steps[lower]) / (steps[upper] - steps[lower])
    # Each width's fit only where it is used (a light sole's path needs the narrowest alone).
    fits = np.full((len(steps), len(z)), np.nan)
    for i, width in enumerate(steps):
        used = np.flatnonzero(((lower == i) & (share < 1.0)) | ((upper == i) & (share > 0.0)))
        if used.size:
            fits[i, used] = local_planes(xy[used], xy, z, float(width))[0]
    columns = np.arange(len(z))
    low = np.where(share < 1.0, (1.0 - share) * fits[lower, columns], 0.0)
    return low + np.where(share > 0.0, share * fits[upper, columns], 0.0)
