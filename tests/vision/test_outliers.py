"""Statistical outlier removal on the pixel grid gives Open3D's result on stereo-like clouds."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from cellctl.vision.outliers import ISOLATED_SPACINGS, inliers_by_mean, mean_neighbour_distances

FOCAL_PX, BASELINE_MM = 1400.0, 80.0


def _stereo_cloud(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sloped, noisy sole-like height field seen from 540 mm, with holes, spikes and isolated specks."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[300:420, 500:660]
    xs, ys = xs.ravel(), ys.ravel()
    z_camera = 540.0 - 0.08 * (xs - 500) - 0.3 * np.clip(ys - 380, 0, None) ** 1.5  # a flat top, a steep flank
    z_camera += rng.normal(0.0, 0.1, xs.size)
    spikes = rng.random(xs.size) < 0.01
    z_camera[spikes] -= rng.uniform(2.0, 10.0, np.count_nonzero(spikes))
    keep = rng.random(xs.size) > 0.05  # unmeasured pixels
    keep &= ~((xs - 560) ** 2 + (ys - 340) ** 2 < 36)  # a hole
    keep &= ~((xs > 630) & (ys < 330) & ((xs + ys) % 7 != 0))  # a sparse corner: specks
    xs, ys, z_camera = xs[keep], ys[keep], z_camera[keep]
    disparity = FOCAL_PX * BASELINE_MM / z_camera
    points = np.column_stack([(xs - 640) * z_camera / FOCAL_PX, (ys - 512) * z_camera / FOCAL_PX, z_camera])
    return np.column_stack([xs, ys]).astype(np.float64), points, BASELINE_MM / disparity


@pytest.mark.parametrize("seed", [0, 1])
def test_same_points_as_open3d(seed: int) -> None:
    pixels, points, spacing = _stereo_cloud(seed)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    _, expected = cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
    kept = inliers_by_mean(mean_neighbour_distances(pixels, points, spacing))
    assert len(kept) < len(points)  # there is something to remove
    assert set(kept.tolist()) == set(np.asarray(expected).tolist())


def _top_with_specks(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A flat, noisy sole top (120 x 80 px, a few unmeasured pixels) seen from 540 mm, and beyond its edge a
    band the matcher could not measure but for a few specks at the top's height, each 5+ px from any other
    point (a dark shadow band's pixels given the sole's disparity). The specks' mask comes last."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[300:380, 500:620]
    xs, ys = xs.ravel(), ys.ravel()
    keep = rng.random(xs.size) > 0.03
    xs, ys = xs[keep], ys[keep]
    speck_x = np.arange(505, 615, 9) + rng.integers(0, 3, 13)
    speck_y = 385 + rng.integers(0, 8, 13)
    xs, ys = np.concatenate([xs, speck_x]), np.concatenate([ys, speck_y])
    z_camera = 540.0 + rng.normal(0.0, 0.1, xs.size)
    disparity = FOCAL_PX * BASELINE_MM / z_camera
    points = np.column_stack([(xs - 640) * z_camera / FOCAL_PX, (ys - 512) * z_camera / FOCAL_PX, z_camera])
    specks = np.zeros(xs.size, bool)
    specks[-len(speck_x) :] = True
    return np.column_stack([xs, ys]).astype(np.float64), points, BASELINE_MM / disparity, specks


def test_isolated_points_are_the_specks_not_the_tops_edge() -> None:
    """The specks beyond the edge are isolated; the top's own points are not, its edge and corners included,
    which the statistical rule drops with them (their neighbours lie on one side only)."""
    for seed in (0, 1):
        pixels, points, spacing, specks = _top_with_specks(seed)
        distance = mean_neighbour_distances(pixels, points, spacing)
        isolated = distance > ISOLATED_SPACINGS * spacing
        outlier = np.ones(len(points), bool)
        outlier[inliers_by_mean(distance)] = False
        assert np.all(isolated[specks])
        assert not np.any(isolated[~specks])
        assert np.any(outlier[~specks])  # the top's edge: outliers, not isolated
