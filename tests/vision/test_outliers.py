"""Statistical outlier removal on the pixel grid gives Open3D's result on stereo-like clouds."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from cellctl.vision.outliers import statistical_inliers as _statistical_inliers

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
    kept = _statistical_inliers(pixels, points, spacing)
    assert len(kept) < len(points)  # there is something to remove
    assert set(kept.tolist()) == set(np.asarray(expected).tolist())
