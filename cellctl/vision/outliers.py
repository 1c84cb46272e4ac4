"""Statistical outlier removal on the pixel grid (Open3D's rule, neighbours from the rectified image)."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from cellctl.stereo.kernels import neighbour_means, window_means

# A point whose 20 nearest points lie more than this many of its pixel spacings away in the mean is isolated: a
# speck of depth with no measured surface round it. On the sole the mean is 1.7 spacings (median), 2.4-2.9 at the
# 99th-99.9th percentile and above 4 at 0-11 of ~150000 points; the specks the matcher leaves beyond a sole's edge
# (its disparity dragged onto a few pixels of a dark shadow band it cannot measure, or of the table beside a
# black sole) read 4-5.6 (14 of the 19 points beyond fresh sole 9339's edge; /work/notes/s22/md.py). The statistical
# rule's limit (mean + 2 sd, ~2.1-2.2 spacings on a sole) also takes the sole's own edge points, whose neighbours
# lie on one side only: those are no specks.
ISOLATED_SPACINGS = 4.0


def inliers_by_mean(mean: np.ndarray) -> np.ndarray:
    """Indices of the points whose mean neighbour distance (`mean_neighbour_distances`, N) is no outlier's:
    at most the mean of them all plus 2 standard deviations (Open3D's std_ratio=2.0). With the distances from
    the image grid, Open3D's remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)."""
    return np.flatnonzero(mean <= mean.mean() + 2.0 * mean.std())


def mean_neighbour_distances(pixels: np.ndarray, points: np.ndarray, spacing_mm: np.ndarray) -> np.ndarray:
    """Each point's mean distance to its 20 nearest points, itself included (N).

    Open3D's remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0) rule: a point is an outlier when this
    exceeds the cloud's mean of it by 2 standard deviations. The neighbours come from the image grid instead
    of a k-d tree (0.07 s instead of Open3D's 0.15 s for ~1.4 10^5 sole points, 2 cores): the sole is a
    height field seen from above, so a point's nearest points are among its nearest pixels. Mostly they are
    the 20 pixels within 2.3 px (5 x 5 without the corners); where that block is not complete or one of the
    16 pixels within 3.2 px is nearer (the sole's edge, holes, steep flanks), the 19 nearest of those 36;
    for the few whose 19 nearest lie farther still, of a 15 x 15 window, then 31, 63 and 127 px wide (in C,
    cellctl.stereo.kernels.window_means; its numpy rule is the reference in tests/stereo/test_cloud_kernels.py);
    for isolated points (spikes, specks; rarely any on the sole) a k-d tree. The means agree with Open3D's to 10^-5 mm (float32 sums).
    """
    grid, rows, cols = _point_grid(pixels, points, margin=_WINDOW_HALVES[-1])
    at = rows * grid.shape[2] + cols
    # The first two cases, one pass over the points in C (cellctl.stereo.kernels; the numpy rule they
    # follow is the reference in tests/vision/test_outliers.py): mostly the 19 nearest are the block's 20
    # (within 2.3 px) but its farthest; else the 19 nearest of the 36 within 3.2 px, capped at 3.6 px.
    mean, exact = neighbour_means(grid, at, spacing_mm, _NEAR_OFFSETS)
    others = np.flatnonzero(~exact)
    if others.size:  # wider windows, in C too, for the points whose 19 nearest lie farther out
        mean[others], settled = window_means(grid, at[others], spacing_mm[others], _WINDOW_HALVES)
        others = others[~settled]
    if others.size:  # isolated points (spikes, specks): their neighbours lie anywhere, ask a k-d tree
        tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
        for k in others:
            mean[k] = np.mean(np.sqrt(np.asarray(tree.search_knn_vector_3d(points[k], 20)[2])))
    return mean


_WINDOW_HALVES = (7, 15, 31, 63)  # 15 x 15 to 127 x 127 pixels, each for fewer points (in C)
_NEAR_BLOCK = [(dx, dy) for dy in range(-2, 3) for dx in range(-2, 3) if 0 < dx * dx + dy * dy <= 5]  # 20
_NEAR = _NEAR_BLOCK + [(dx, dy) for dy in range(-3, 4) for dx in range(-3, 4) if 5 < dx * dx + dy * dy <= 10]  # + 16
_NEAR_OFFSETS = np.array(_NEAR, np.int32)


def _point_grid(pixels: np.ndarray, points: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points as a 3 x H x W float32 image over their pixels' bounding box plus `margin` (NaN elsewhere),
    and each point's (row, col) in it."""
    x, y = pixels.T.astype(np.int64)
    cols, rows = x - int(x.min()) + margin, y - int(y.min()) + margin
    # Filled as H x W x 3 (each pixel's x y z side by side, as the kernels read them) and handed on as its
    # 3 x H x W view: the kernels' arguments are then this array itself, not a transposed copy per kernel.
    grid = np.full((int(rows.max()) + margin + 1, int(cols.max()) + margin + 1, 3), np.nan, np.float32)
    grid[rows, cols] = points
    return np.moveaxis(grid, -1, 0), rows, cols
