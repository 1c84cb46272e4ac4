"""surface.table_planes: a patch's affine disparity taken to the table frame as a plane, without its pixels."""

from __future__ import annotations

import numpy as np

from cellctl.vision.surface import TRIM, heights_on_planes, robust_planes, table_planes

FOCAL, CX, CY, BASELINE = 1400.0, 640.0, 480.0, 120.0
# OpenCV's reprojection (stereoRectify's Q, left camera's frame): (x, y, d, 1) -> (X, Y, Z, W)
Q = np.array([[1.0, 0, 0, -CX], [0, 1.0, 0, -CY], [0, 0, 0, FOCAL], [0, 0, 1.0 / BASELINE, 0]])


def _table_to_camera() -> np.ndarray:
    """The camera 550 mm above a table tilted a few degrees, looking down."""
    tilt = np.radians(4.0)
    look_down = np.diag([1.0, -1.0, -1.0])
    roll = np.array([[1.0, 0, 0], [0, np.cos(tilt), -np.sin(tilt)], [0, np.sin(tilt), np.cos(tilt)]])
    pose = np.eye(4)
    pose[:3, :3] = roll @ look_down
    pose[:3, 3] = [10.0, -5.0, 550.0]
    return pose


def _patch_fit(table_points: np.ndarray, table_to_camera: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The affine disparity (a, b, c) about `centre` (pixels) that the images show for these table points, by least
    squares over their pixels, as subpixel.refine_patches would fit it."""
    camera = table_points @ table_to_camera[:3, :3].T + table_to_camera[:3, 3]
    pixels = camera[:, :2] / camera[:, 2:3] * FOCAL + [CX, CY]
    disparity = FOCAL * BASELINE / camera[:, 2]
    design = np.column_stack([np.ones(len(pixels)), pixels - centre])
    return np.linalg.lstsq(design, disparity, rcond=None)[0]


def test_a_patch_of_a_sloping_top_gives_its_height_and_normal() -> None:
    pose = _table_to_camera()
    gradient, z0 = np.array([0.12, -0.07]), 14.0
    queries = np.array([[-60.0, 20.0], [35.0, -40.0], [110.0, 5.0]])
    rng = np.random.default_rng(2)
    params, centres = [], []
    for query in queries:
        offsets = rng.uniform(-4.0, 4.0, (150, 2))
        xy = query + offsets
        points = np.column_stack([xy, z0 + xy @ gradient])
        camera = np.append(query, z0 + query @ gradient) @ pose[:3, :3].T + pose[:3, 3]
        centre = camera[:2] / camera[2] * FOCAL + [CX, CY] + rng.uniform(-1.0, 1.0, 2)  # not quite at the query
        params.append(_patch_fit(points, pose, centre))
        centres.append(centre)
    z, normals = heights_on_planes(table_planes(np.array(params), np.array(centres), Q, pose), queries)
    np.testing.assert_allclose(z, z0 + queries @ gradient, atol=1e-6)
    expected = np.append(-gradient, 1.0) / np.linalg.norm(np.append(-gradient, 1.0))
    np.testing.assert_allclose(normals, np.tile(expected, (3, 1)), atol=1e-9)


def test_an_upright_plane_has_no_height() -> None:
    """A plane that stands upright on the table (an affine disparity of a wall seen edge-on) gives NaN, not inf."""
    planes = np.array([[1.0, 0.0, 0.0, -5.0], [0.0, 0.1, -1.0, 3.0]])
    z, _ = heights_on_planes(planes, np.array([[5.0, 0.0], [0.0, 10.0]]))
    assert np.isnan(z[0])
    assert z[1] == 4.0


def _reference_plane(points: np.ndarray, at: np.ndarray) -> tuple[float, np.ndarray]:
    """One query's trimmed plane as SoleSurface.cloud_planes fitted it query by query before (lstsq, np.quantile)."""

    def fit(p: np.ndarray) -> np.ndarray:
        design = np.column_stack([np.ones(len(p)), p[:, 0] - at[0], p[:, 1] - at[1]])
        return np.linalg.lstsq(design, p[:, 2], rcond=None)[0]

    coef = fit(points)
    residual = points[:, 2] - (coef[0] + coef[1] * (points[:, 0] - at[0]) + coef[2] * (points[:, 1] - at[1]))
    lo, hi = np.quantile(residual, [TRIM, 1.0 - TRIM])
    keep = (residual >= lo) & (residual <= hi)
    if keep.sum() >= 3:
        coef = fit(points[keep])
    normal = np.array([-coef[1], -coef[2], 1.0])
    return float(coef[0]), normal / np.linalg.norm(normal)


def test_trimmed_planes_of_many_queries_at_once_are_those_fitted_one_by_one() -> None:
    rng = np.random.default_rng(5)
    sizes = [3, 4, 12, 13, 57, 200]  # the fewest points a plane needs, and a few more
    at = rng.uniform(-50, 50, (len(sizes), 2))
    chunks = []
    for (x, y), size in zip(at, sizes, strict=True):
        xy = np.column_stack([x, y]) + rng.uniform(-6, 6, (size, 2))
        z = 20.0 + 0.1 * (xy[:, 0] - x) - 0.3 * (xy[:, 1] - y) + rng.normal(0.0, 0.3, size)
        z[: size // 10] += 8.0  # outliers the trim drops
        chunks.append(np.column_stack([xy, z]))
    chunks[1][:, 2] = chunks[1][0, 2]  # ties in the residuals
    points = np.vstack(chunks)
    ids = np.repeat(np.arange(len(sizes)), sizes)
    z0, normals = robust_planes(points, at, ids)
    for k, chunk in enumerate(chunks):
        ref_z, ref_normal = _reference_plane(chunk, at[k])
        assert abs(z0[k] - ref_z) < 1e-9
        np.testing.assert_allclose(normals[k], ref_normal, atol=1e-9)
    assert abs(normals[5] @ np.array([-0.1, 0.3, 1.0]) / np.linalg.norm([-0.1, 0.3, 1.0]) - 1.0) < 1e-3
