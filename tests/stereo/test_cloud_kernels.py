"""The measurement's C kernels (csrc/cloud_kernels.c) against their numpy formulations, and their bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.stereo.kernels import (
    cell_counts,
    cells_marked,
    disc_dilate,
    neighbour_means,
    patch_sample,
    patch_shift,
    patch_step,
    points_in_polygon,
    window_means,
)
from cellctl.stereo.pointgrid import PointGrid
from cellctl.vision import outliers, subpixel

from ..vision.test_outliers import BASELINE_MM, FOCAL_PX, _stereo_cloud


def _numpy_neighbour_means(grid: np.ndarray, at: np.ndarray, spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rule as numpy passes over the points (cellctl.vision.outliers before the kernel)."""
    flat = grid.reshape(3, -1)
    centre = flat[:, at]

    def distances(dx: int, dy: int) -> np.ndarray:
        offset = np.take(flat, at + (dy * grid.shape[2] + dx), axis=1) - centre
        return np.nan_to_num(np.sqrt(np.einsum("ij,ij->j", offset, offset)), nan=np.inf)

    near = np.stack([distances(dx, dy) for dx, dy in outliers._NEAR])
    block = near[:20]
    largest = block.max(axis=0)
    second = np.partition(block, -2, axis=0)[-2]
    with np.errstate(invalid="ignore"):
        mean = (block.sum(axis=0) - largest) / 20.0
    exact = np.isfinite(largest) & (second <= np.fmin(near[20:].min(axis=0), 3.5 * spacing))
    rest = np.flatnonzero(~exact)
    nearest = np.partition(near[:, rest], 18, axis=0)[:19]
    mean[rest] = np.sum(np.fmin(nearest, 3.6 * spacing[rest]), axis=0) / 20.0
    exact[rest] = nearest.max(axis=0) <= 0.95 * 3.6 * spacing[rest]
    return mean, exact


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_neighbour_means_follow_the_numpy_rule(seed: int) -> None:
    pixels, points, spacing = _stereo_cloud(seed)
    grid, rows, cols = outliers._point_grid(pixels, points, margin=3)
    at = rows * grid.shape[2] + cols
    mean, exact = neighbour_means(grid, at, spacing, outliers._NEAR_OFFSETS)
    expected_mean, expected_exact = _numpy_neighbour_means(grid, at, spacing)
    assert 0 < np.count_nonzero(~expected_exact)  # the cloud has edges, holes and specks: not only the block case
    np.testing.assert_array_equal(exact, expected_exact)
    np.testing.assert_array_equal(mean, expected_mean)  # float32, summed in the same order


def _block_case(grid: np.ndarray, at: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """The points whose mean is the block's (the first case of the rule)."""
    flat = grid.reshape(3, -1)
    offset = flat[
        :, at[None, :] + (outliers._NEAR_OFFSETS[:, 1, None] * grid.shape[2] + outliers._NEAR_OFFSETS[:, 0, None])
    ]
    offset = offset - flat[:, at][:, None, :]
    near = np.nan_to_num(np.sqrt((offset[0] * offset[0] + offset[1] * offset[1]) + offset[2] * offset[2]), nan=np.inf)
    block = np.sort(near[:20], axis=0)
    return np.isfinite(block[19]) & (block[18] <= np.fmin(near[20:].min(axis=0), 3.5 * spacing))


def _sequential_slow_means(grid: np.ndarray, at: np.ndarray, spacing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The slow case's rule with the kernel's own summation order: each point's 36 distances sorted (missing
    ones infinite), the first 19 each capped at 3.6 spacings and summed in double in ascending order."""
    flat = grid.reshape(3, -1)
    offset = flat[
        :, at[None, :] + (outliers._NEAR_OFFSETS[:, 1, None] * grid.shape[2] + outliers._NEAR_OFFSETS[:, 0, None])
    ]
    offset = offset - flat[:, at][:, None, :]
    squared = (offset[0] * offset[0] + offset[1] * offset[1]) + offset[2] * offset[2]  # float32, as the kernel
    near = np.sort(np.nan_to_num(np.sqrt(squared), nan=np.inf), axis=0)[:19]
    reach = 3.6 * spacing
    capped = np.fmin(near.astype(np.float64), reach)
    total = np.cumsum(capped, axis=0)[-1]  # one addition after the other
    return (total / 20.0).astype(np.float32), near[18] <= 0.95 * reach


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_neighbour_means_slow_case_sorts_ties_holes_and_partial_lane_groups(seed: int) -> None:
    """Points whose block is incomplete or not the nearest go through the kernel's sorting network a group of
    lanes at a time: ties (a quantised grid), holes of every density and any count of such points give the
    sorted rule's means, on one thread and on two."""
    rng = np.random.default_rng(seed)
    height, width = 60, 70 + seed
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    z = rng.normal(0.0, (0.05, 0.4, 1.5, 4.0)[seed], (height, width)).astype(np.float32)
    grid = np.stack([0.4 * xs, 0.4 * ys, z])
    if seed % 2 == 0:
        grid = np.round(grid * 4.0) / 4.0  # equal distances everywhere
    grid[:, rng.random((height, width)) < (0.05, 0.3, 0.6, 0.15)[seed]] = np.nan
    rows, cols = np.nonzero(np.isfinite(grid[2, 3:-3, 3:-3]))
    at = (rows + 3) * width + cols + 3
    at = at[: len(at) - seed]  # a count that leaves the last group of lanes part full
    spacing = rng.uniform(0.3, 0.5, len(at))
    mean, exact = neighbour_means(grid, at, spacing, outliers._NEAR_OFFSETS, threads=1)
    expected_mean, expected_exact = _numpy_neighbour_means(grid, at, spacing)
    slow_mean, slow_exact = _sequential_slow_means(grid, at, spacing)
    slow = np.flatnonzero(~_block_case(grid, at, spacing))
    assert len(slow) > 100  # (1024-point blocks: each ends with a part-full group of lanes)
    np.testing.assert_array_equal(exact, expected_exact)
    np.testing.assert_array_equal(mean[slow], slow_mean[slow])
    np.testing.assert_array_equal(exact[slow], slow_exact[slow])
    for a, b in zip((mean, exact), neighbour_means(grid, at, spacing, outliers._NEAR_OFFSETS, threads=2), strict=True):
        np.testing.assert_array_equal(a, b)


def test_neighbour_means_refuse_points_at_the_grid_edge() -> None:
    pixels, points, spacing = _stereo_cloud(0)
    grid, rows, cols = outliers._point_grid(pixels, points, margin=2)  # one pixel short of the reach
    with pytest.raises(ValueError, match="outside its array"):
        neighbour_means(grid, rows * grid.shape[2] + cols, spacing, outliers._NEAR_OFFSETS)
    with pytest.raises(ValueError, match="36 x 2"):
        neighbour_means(grid, rows * grid.shape[2] + cols, spacing, outliers._NEAR_OFFSETS[:20])
    with pytest.raises(ValueError, match="3 x H x W"):
        neighbour_means(grid[:2], rows * grid.shape[2] + cols, spacing, outliers._NEAR_OFFSETS)


def _numpy_window_means(
    grid: np.ndarray, at: np.ndarray, spacing: np.ndarray, halves: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The wider windows' rule as numpy passes (cellctl.vision.outliers before the kernel): per window, the 19
    nearest of its pixels, each capped at half + 1 spacings; a point leaves once they lie within 0.95 of that."""
    flat = grid.reshape(3, -1)
    centre = flat[:, at]
    mean = np.full(len(at), np.nan, np.float32)
    settled = np.zeros(len(at), bool)
    others = np.arange(len(at))
    for half in halves:
        window = np.array([(dx, dy) for dy in range(-half, half + 1) for dx in range(-half, half + 1) if dx or dy])
        neighbours = flat[:, at[others, None] + window[:, 1] * grid.shape[2] + window[:, 0]]  # 3 x P x M
        offset = neighbours - centre[:, others, None]
        distance = np.nan_to_num(np.sqrt(np.einsum("ijk,ijk->jk", offset, offset)), nan=np.inf)
        beyond = (half + 1) * spacing[others, None]
        nearest = np.partition(distance, 18, axis=1)[:, :19]
        mean[others] = np.sum(np.fmin(nearest, beyond), axis=1) / 20.0
        leaving = np.max(nearest, axis=1) <= 0.95 * beyond[:, 0]
        settled[others[leaving]] = True
        others = others[~leaving]
    return mean, settled


def _sparse_cloud(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stereo-like cloud with a thinned band (points 2-12 px apart), a far cluster and lone specks."""
    pixels, points, spacing = _stereo_cloud(seed)
    rng = np.random.default_rng(100 + seed)
    x, y = pixels.T
    keep = ~((x > 600) & (x < 640) & (rng.random(len(x)) > 0.08))  # a band where few points are left
    pixels, points, spacing = pixels[keep], points[keep], spacing[keep]
    far = np.column_stack([rng.integers(700, 760, 40), rng.integers(250, 260, 40)]).astype(np.float64)  # 60 px off
    lone = np.array([[480.0, 290.0], [520.0, 460.0], [690.0, 430.0], [900.0, 600.0]])  # isolated, one beyond 63 px
    extra = np.unique(np.vstack([far, lone]), axis=0)
    z = 540.0 + rng.normal(0.0, 3.0, len(extra))
    extra_points = np.column_stack([(extra[:, 0] - 640) * z / FOCAL_PX, (extra[:, 1] - 512) * z / FOCAL_PX, z])
    return (
        np.vstack([pixels, extra]),
        np.vstack([points, extra_points]),
        np.concatenate([spacing, BASELINE_MM / (FOCAL_PX * BASELINE_MM / z)]),
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_window_means_follow_the_numpy_rule(seed: int) -> None:
    pixels, points, spacing = _sparse_cloud(seed)
    halves = outliers._WINDOW_HALVES
    grid, rows, cols = outliers._point_grid(pixels, points, margin=halves[-1])
    at = rows * grid.shape[2] + cols
    _, exact = neighbour_means(grid, at, spacing, outliers._NEAR_OFFSETS)
    rest = np.flatnonzero(~exact)
    mean, settled = window_means(grid, at[rest], spacing[rest], halves)
    expected_mean, expected_settled = _numpy_window_means(grid, at[rest], spacing[rest], halves)
    assert 0 < np.count_nonzero(~expected_settled)  # isolated points: some reach past the widest window
    for half in halves[1:]:  # and some settle in each wider window
        narrower = _numpy_window_means(grid, at[rest], spacing[rest], tuple(h for h in halves if h < half))[1]
        assert np.count_nonzero(expected_settled & ~narrower) > 0, half
    np.testing.assert_array_equal(settled, expected_settled)
    np.testing.assert_array_equal(mean, expected_mean)  # float32 of the double sums
    one = window_means(grid, at[rest], spacing[rest], halves, threads=1)
    two = window_means(grid, at[rest], spacing[rest], halves, threads=2)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)


def test_window_means_refuse_bad_input() -> None:
    pixels, points, spacing = _stereo_cloud(0)
    grid, rows, cols = outliers._point_grid(pixels, points, margin=15)
    at = rows * grid.shape[2] + cols
    with pytest.raises(ValueError, match="outside its array"):  # the 31 px window reaches past the grid
        window_means(grid, at, spacing, (7, 31))
    for halves in [(), (7, 7), (15, 7), (0,), (300,)]:
        with pytest.raises(ValueError, match="out of range"):
            window_means(grid, at, spacing, halves)
    with pytest.raises(ValueError, match="3 x H x W"):
        window_means(grid[:2], at, spacing, (7,))
    with pytest.raises(ValueError, match="halves"):
        window_means(grid, at, spacing, ((7, 15),))  # type: ignore[arg-type]


def _patches(seed: int, count: int = 40) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    sizes = np.where(rng.random(count) < 0.2, 0, rng.integers(12, 60, count))  # empty patches too
    count, pixels = len(sizes), int(sizes.sum())
    ids = np.repeat(np.arange(count), sizes)
    return {
        "ids": ids,
        "starts": np.concatenate([[0], np.cumsum(sizes)]),
        "l_dev": rng.normal(0, 10, pixels),
        "right": rng.normal(100, 20, (pixels, 2)).astype(np.float32),
        "dx": rng.uniform(-8, 8, pixels),
        "dy": rng.uniform(-8, 8, pixels),
        "params": rng.normal(0, 1, (count, 3)),
        "x": rng.uniform(0, 1000, pixels).astype(np.float32),
    }


@pytest.mark.parametrize("seed", [0, 1])
def test_patch_step_is_the_numpy_gauss_newton_step(seed: int) -> None:
    p = _patches(seed)
    sums = subpixel.PatchSums(p["ids"], len(p["starts"]) - 1)
    l_dev = p["l_dev"] - sums.means_at_pixels(p["l_dev"])
    l_energy = sums(l_dev**2)
    r_val, r_grad = p["right"].astype(np.float64).T
    dx, dy = p["dx"], p["dy"]
    basis = np.vstack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy])
    expected = subpixel._gauss_newton_step(l_dev, l_energy, r_val - sums.means_at_pixels(r_val), r_grad, basis, sums)
    step = patch_step(p["starts"], l_dev, l_energy, p["right"], dx, dy)
    empty = sums.sizes == 0
    assert np.all(step[empty] == 0.0)
    np.testing.assert_allclose(step[~empty], expected[~empty], rtol=1e-8, atol=1e-10)  # summation order


def test_patch_shift_is_x_minus_the_patch_plane() -> None:
    p = _patches(3)
    a, b, c = p["params"][p["ids"]].T
    expected = (p["x"] - (a + b * p["dx"] + c * p["dy"])).astype(np.float32)
    np.testing.assert_array_equal(patch_shift(p["starts"], p["params"], p["x"], p["dx"], p["dy"]), expected)


def test_kernels_give_identical_results_on_one_and_two_threads() -> None:
    """Each output element is computed whole by one thread: the thread count must not change a bit."""
    pixels, points, spacing = _stereo_cloud(1)
    grid, rows, cols = outliers._point_grid(pixels, points, margin=3)
    at = rows * grid.shape[2] + cols
    assert len(at) >= 4096  # above the kernels' threshold for more than one thread
    one = neighbour_means(grid, at, spacing, outliers._NEAR_OFFSETS, threads=1)
    two = neighbour_means(grid, at, spacing, outliers._NEAR_OFFSETS, threads=2)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)
    p = _patches(4, count=2000)
    assert p["starts"][-1] >= 4096
    args = (p["starts"], p["l_dev"], np.abs(p["l_dev"][: len(p["starts"]) - 1]) + 1.0, p["right"], p["dx"], p["dy"])
    np.testing.assert_array_equal(patch_step(*args, threads=1), patch_step(*args, threads=2))
    shift = (p["starts"], p["params"], p["x"], p["dx"], p["dy"])
    np.testing.assert_array_equal(patch_shift(*shift, threads=1), patch_shift(*shift, threads=2))
    with pytest.raises(ValueError, match="threads"):
        patch_shift(*shift, threads=-1)


def test_patch_kernels_refuse_inconsistent_input() -> None:
    p = _patches(4)
    unsorted = p["starts"].copy()
    unsorted[[10, 11]] = unsorted[[11, 10]] + np.array([0, 5])  # a patch that ends before it starts
    with pytest.raises(ValueError, match="outside its array"):
        patch_shift(unsorted, p["params"], p["x"], p["dx"], p["dy"])
    with pytest.raises(ValueError, match="per-pixel"):
        patch_step(p["starts"], p["l_dev"][:-1], np.ones(len(p["starts"]) - 1), p["right"], p["dx"], p["dy"])
    with pytest.raises(ValueError, match="one value per patch"):
        patch_step(p["starts"], p["l_dev"], np.ones(3), p["right"], p["dx"], p["dy"])
    with pytest.raises(ValueError, match="x 2"):
        patch_step(p["starts"], p["l_dev"], np.ones(len(p["starts"]) - 1), p["right"][:, 0], p["dx"], p["dy"])


def test_patch_fits_through_the_kernels_find_a_known_shift() -> None:
    """End to end (cellctl.vision.subpixel.refine_patches): a textured right image shifted by 3 px is found
    from a start 0.4 px off, to well under the 0.03 px a height needs."""
    rng = np.random.default_rng(5)
    left = cv2.GaussianBlur(rng.normal(100, 30, (80, 120)).astype(np.float32), (0, 0), 1.2)
    right = np.roll(left, -3, axis=1)  # right(x) = left(x + 3): disparity 3
    centres = np.array([[60.0, 40.0], [40.0, 30.0], [80.0, 50.0]])
    fit = subpixel.refine_patches(left, right, np.ones(left.shape, bool), centres, 8.0, np.full(3, 2.6))
    assert fit.ok.all()
    np.testing.assert_allclose(fit.params[:, 0], 3.0, atol=0.01)
    np.testing.assert_allclose(fit.params[:, 1:], 0.0, atol=0.005)


def _plane_points(seed: int, count: int = 20000) -> np.ndarray:
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-80, 120, count), rng.uniform(-30, 50, count), rng.normal(20, 3, count)])
    points[:50, :2] = np.round(points[:50, :2])  # points on cell corners and edges too
    return points


@pytest.mark.parametrize("cell", [1.0, 2.0, 3.7])
def test_point_grid_finds_what_a_kd_tree_finds(cell: float) -> None:
    """Radius counts, medians and neighbours as Open3D's k-d tree over (x, y, 0) gives them (cellctl.vision.surface
    used the tree before the grid)."""
    import open3d as o3d

    points = _plane_points(0)
    grid = PointGrid(points[:, :2], cell, points[:, 2])
    flat = np.column_stack([points[:, :2], np.zeros(len(points))])
    tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(flat)))
    rng = np.random.default_rng(1)
    queries = np.column_stack([rng.uniform(-95, 135, 150), rng.uniform(-45, 65, 150)])
    queries[:10] = points[:10, :2] + np.array([cell, 0.0])  # a neighbour exactly at the radius (1 mm)
    for radius in (1.0, 4.0, 10.0):
        counts, medians = grid.radius_medians(queries, radius)
        np.testing.assert_array_equal(grid.radius_counts(queries, radius), counts)
        member_counts, members = grid.radius_members(queries, radius)  # every query's neighbours, one flat array
        np.testing.assert_array_equal(member_counts, counts)
        found = np.split(members, np.cumsum(member_counts)[:-1])
        for k, (x, y) in enumerate(queries):
            index = np.asarray(tree.search_radius_vector_3d(np.array([x, y, 0.0]), radius)[1], np.int64)
            np.testing.assert_array_equal(np.sort(found[k]), np.sort(index))
            assert counts[k] == len(index)
            if len(index):
                assert medians[k] == np.median(points[index, 2])
            else:
                assert np.isnan(medians[k])


def test_point_grid_cell_medians_and_threads() -> None:
    points = _plane_points(2)
    grid = PointGrid(points[:, :2], 1.0, points[:, 2], origin=(-81.0, -31.0), shape=(82, 202))
    medians = grid.cell_upper_medians()
    col = np.floor(points[:, 0] + 81.0).astype(int)
    row = np.floor(points[:, 1] + 31.0).astype(int)
    for r, c in [(row[0], col[0]), (row[7], col[7]), (40, 100)]:
        z = np.sort(points[(row == r) & (col == c), 2])
        assert medians[r, c] == z[len(z) // 2]
    assert np.isnan(medians[0, 0])  # no point there
    queries = points[:5000, :2]  # enough queries and cells for two threads
    one, two = (PointGrid(points[:, :2], 1.0, points[:, 2], threads=t) for t in (1, 2))
    np.testing.assert_array_equal(one.radius_medians(queries, 4.0), two.radius_medians(queries, 4.0))
    np.testing.assert_array_equal(one.cell_upper_medians(), two.cell_upper_medians())


def test_point_grid_refuses_bad_input() -> None:
    points = _plane_points(3, 100)
    with pytest.raises(ValueError, match="positive"):
        PointGrid(points[:, :2], 0.0)
    with pytest.raises(ValueError, match="finite"):
        PointGrid(np.array([[0.0, np.nan]]), 1.0)
    with pytest.raises(ValueError, match="outside its array"):  # a given raster that does not hold the points
        PointGrid(points[:, :2], 1.0, origin=(0.0, 0.0), shape=(5, 5))
    with pytest.raises(ValueError, match="without values"):
        PointGrid(points[:, :2], 1.0).radius_medians(points[:3, :2], 2.0)
    with pytest.raises(ValueError, match="negative"):
        PointGrid(points[:, :2], 1.0, points[:, 2]).radius_medians(points[:3, :2], -1.0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_points_in_polygon_is_opencvs_point_polygon_test(seed: int) -> None:
    """Inside, outside and on the boundary exactly as cv2.pointPolygonTest (Footprint.filled used it point by
    point): vertices on the integer and half-integer grid put many points on edges and vertices, and a
    polygon from random vertices crosses itself."""
    rng = np.random.default_rng(seed)
    if seed % 2:
        polygon = np.round(rng.uniform(0, 30, (40, 2)) * 2) / 2
    else:
        angle = np.sort(rng.uniform(0, 2 * np.pi, 150))
        polygon = np.round(15 + rng.uniform(4, 14, 150)[:, None] * np.column_stack([np.cos(angle), np.sin(angle)]))
    polygon = polygon.astype(np.float32)
    ys, xs = np.mgrid[0:31, 0:31]
    points = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float32)
    expected = [cv2.pointPolygonTest(polygon.reshape(-1, 1, 2), (float(x), float(y)), False) for x, y in points]
    assert 0 in expected and 1 in expected and -1 in expected
    np.testing.assert_array_equal(points_in_polygon(polygon, points), expected)
    with pytest.raises(ValueError, match="sorted by y"):
        points_in_polygon(polygon, points[::-1])


def test_patch_sample_is_remap_of_patch_shift() -> None:
    """Bicubic samples on whole rows where the patch planes put the pixels: what cv2.remap (INTER_CUBIC,
    BORDER_REPLICATE) gives at patch_shift's positions, to ~1e-6 of the value (OpenCV's arithmetic differs in
    its order), also past both sides of the image; the same on one and two threads."""
    p = _patches(5, count=300)
    rng = np.random.default_rng(6)
    image = cv2.GaussianBlur(rng.normal(100, 40, (50, 300, 2)).astype(np.float32), (0, 0), 1.0)
    pixels = len(p["x"])
    rows = rng.integers(0, 50, pixels)
    x = rng.uniform(-10, 310, pixels).astype(np.float32)
    shifted = patch_shift(p["starts"], p["params"], x, p["dx"], p["dy"])
    expected = cv2.remap(
        image,
        shifted.reshape(1, -1),
        rows.astype(np.float32).reshape(1, -1),
        cv2.INTER_CUBIC,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(-1, 2)
    args = (p["starts"], p["params"], x, p["dx"], p["dy"], rows, image)
    one, two = patch_sample(*args, threads=1), patch_sample(*args, threads=2)
    np.testing.assert_allclose(one, expected, rtol=0, atol=1e-5 * np.abs(image).max())
    np.testing.assert_array_equal(one, two)
    with pytest.raises(ValueError, match="H x W x 2"):
        patch_sample(*args[:-1], image[..., 0])
    with pytest.raises(ValueError, match="outside its array"):
        patch_sample(*args[:-2], np.full(pixels, 50), image)


def test_patch_sample_vector_kernel_gives_the_scalar_kernels_bits() -> None:
    """The AVX2 kernel (where the CPU has it) computes every sample with the scalar rule's operations in its order:
    the same bits, also for patches of 0-3 pixels (no whole vector), columns past either side of the image, a NaN
    or infinite plane, whole-pixel positions and images narrower than the four columns."""
    rng = np.random.default_rng(11)
    for trial in range(60):
        height, width = int(rng.integers(1, 30)), int(rng.integers(1, 200))
        sizes = rng.integers(0, 30, int(rng.integers(1, 20)))
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        pixels = int(starts[-1])
        params = rng.normal(0.0, 20.0, (len(sizes), 3)) * [1.0, 0.05, 0.05]
        params[0, trial % 3] = (np.nan, np.inf, -np.inf)[trial % 3]
        x = rng.uniform(-20, width + 20, pixels).astype(np.float32)
        x[::3] = np.round(x[::3])
        args = (starts, params, x, rng.normal(0, 8, pixels), rng.normal(0, 8, pixels))
        rows = rng.integers(0, height, pixels)
        image = rng.normal(100, 40, (height, width, 2)).astype(np.float32)
        vector = patch_sample(*args, rows, image, threads=1)
        np.testing.assert_array_equal(vector, patch_sample(*args, rows, image, threads=1, simd=False))


def test_patch_fits_in_row_groups_are_the_fits_of_one_call() -> None:
    """refine_patches fits patches whose rows lie far apart (a heel and a toe) group by group, each filtering
    only its own rows: the same parameters, flags and pixels, bit for bit, as one call over all patches."""
    rng = np.random.default_rng(7)
    left = cv2.GaussianBlur(rng.normal(100, 30, (400, 200)).astype(np.float32), (0, 0), 1.2)
    right = np.roll(left, -3, axis=1)
    centres = np.array([[60.0, 40.0], [100.0, 350.0], [80.0, 55.0], [140.0, 330.0], [100.0, 200.0]])
    mask = np.ones(left.shape, bool)
    start = np.full(len(centres), 2.7)
    assert len(subpixel._row_groups(centres[:, 1], 10.0)) == 3
    grouped = subpixel.refine_patches(left, right, mask, centres, 10.0, start)
    ids, pixels = subpixel.disc_pixels(mask, centres, 10.0)
    params = np.column_stack([start, np.zeros((len(start), 2))])
    whole = subpixel.fit_disparity_planes(left, right, ids, pixels, centres, params)
    np.testing.assert_array_equal(grouped.params, whole.params)
    np.testing.assert_array_equal(grouped.ok, whole.ok)
    np.testing.assert_array_equal(grouped.ids, whole.ids)
    np.testing.assert_array_equal(grouped.xy, whole.xy)
    for a, b in zip(grouped.pixels, whole.pixels, strict=True):
        np.testing.assert_array_equal(a, b)


def _numpy_cells(xy: np.ndarray, origin: tuple[float, float], cell: float, shape: tuple[int, int]):  # noqa: ANN202
    """Footprint.cells' numpy rule: (row, col, inside), clipped."""
    # Not-a-number and infinite coordinates cast to an integer out of every range: `inside` says False for
    # them, which is the rule; numpy warns about the cast itself.
    with np.errstate(invalid="ignore", over="ignore"):
        col = np.floor((xy[:, 0] - origin[0]) / cell).astype(np.int64)
        row = np.floor((xy[:, 1] - origin[1]) / cell).astype(np.int64)
    inside = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    return np.clip(row, 0, shape[0] - 1), np.clip(col, 0, shape[1] - 1), inside


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cell_counts_and_marks_follow_the_numpy_rule(seed: int) -> None:
    rng = np.random.default_rng(seed)
    points = np.column_stack(
        [rng.uniform(-40.0, 90.0, 20000), rng.uniform(-30.0, 60.0, 20000), rng.normal(0, 5, 20000)]
    )
    # Points on cell corners and edges (where floor decides), off the raster, and not numbers.
    points[:500, :2] = np.round(points[:500, :2] * 4.0) / 4.0
    points[500:510, 0] = [np.nan, np.inf, -np.inf, 1e300, -1e300, np.nan, 0.0, 1.0, 2.0, 3.0]
    points[510:515, 1] = [np.nan, np.inf, -np.inf, 1e300, -1e300]
    origin, cell, shape = (-12.25, -7.5), 0.25, (200, 330)
    mask = (rng.random(shape) < 0.4).astype(np.uint8)
    row, col, inside = _numpy_cells(points[:, :2], origin, cell, shape)
    expected = np.bincount(row[inside] * shape[1] + col[inside], minlength=shape[0] * shape[1])
    assert 1000 < inside.sum() < len(points) - 1000  # both kinds
    with np.errstate(over="ignore"):  # 1e300 becomes infinity in float32, another point off the raster
        single = points[:, :2].astype(np.float32)
    for xy in (points[:, :2], np.ascontiguousarray(points[:, :2]), points[::3, :2], single):
        row, col, inside = _numpy_cells(np.asarray(xy, np.float64), origin, cell, shape)
        expected = np.bincount(row[inside] * shape[1] + col[inside], minlength=mask.size).reshape(shape)
        counts = cell_counts(xy, origin, cell, shape)
        assert counts.dtype == np.float32
        np.testing.assert_array_equal(counts, expected.astype(np.float32))
        np.testing.assert_array_equal(cells_marked(xy, origin, cell, mask), inside & (mask[row, col] > 0))
    assert cell_counts(np.zeros((0, 2)), origin, cell, shape).sum() == 0
    assert cells_marked(np.zeros((0, 2)), origin, cell, mask).shape == (0,)


def test_cell_counts_and_marks_refuse_bad_input() -> None:
    xy = np.zeros((3, 2))
    with pytest.raises(ValueError, match="N x 2"):
        cell_counts(np.zeros(4), (0.0, 0.0), 0.25, (4, 4))
    with pytest.raises(ValueError, match="cells"):
        cell_counts(xy, (0.0, 0.0), 0.25, (0, 4))
    with pytest.raises(ValueError, match="out of range"):
        cell_counts(xy, (0.0, 0.0), 0.0, (4, 4))
    with pytest.raises(ValueError, match="out of range"):
        cells_marked(xy, (0.0, 0.0), -1.0, np.ones((4, 4), np.uint8))
    with pytest.raises(ValueError, match="raster"):
        cells_marked(xy, (0.0, 0.0), 0.25, np.ones(4, np.uint8))


def _ellipse_runs(size: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's size x size elliptic element and the half widths of its centred runs, row by row."""
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return disc, np.array([size // 2 - int(np.flatnonzero(row)[0]) for row in disc], np.int32)


@pytest.mark.parametrize("size", [1, 3, 5, 9, 17, 31, 61])
def test_disc_dilation_and_erosion_are_opencvs(size: int) -> None:
    """The disc kernel dilates as cv2.dilate and (of the zero cells, complemented) erodes as cv2.erode with
    OpenCV's elliptic element and default border: blobs at and off the raster's edges, holes, specks, thin
    rasters, an empty and a full one."""
    rng = np.random.default_rng(size)
    disc, half = _ellipse_runs(size)
    shapes = [(120, 170), (37, 211), (1, 90), (80, 1), (2, 2)]
    for k, shape in enumerate(shapes * 4):
        mask = np.zeros(shape, np.uint8)
        for _ in range(3):
            centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
            axes = (int(rng.integers(1, 70)), int(rng.integers(1, 50)))
            cv2.ellipse(mask, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        mask &= (rng.random(shape) < rng.uniform(0.6, 1.0)).astype(np.uint8)
        mask[rng.random(shape) < 0.01] = 1
        if k == 5:
            mask[:] = 0
        if k == 6:
            mask[:] = 1
        np.testing.assert_array_equal(disc_dilate(mask, half), cv2.dilate(mask, disc))
        np.testing.assert_array_equal(disc_dilate(mask, half, of_zero=True, invert=True), cv2.erode(mask, disc))
        np.testing.assert_array_equal(disc_dilate(mask, half, invert=True), 1 - cv2.dilate(mask, disc))


def test_disc_dilation_refuses_bad_input() -> None:
    mask = np.ones((10, 10), np.uint8)
    with pytest.raises(ValueError, match="odd number of runs"):
        disc_dilate(mask, np.array([1, 2], np.int32))
    with pytest.raises(ValueError, match="outside its array"):
        disc_dilate(mask, np.array([0, -1, 0], np.int32))
    with pytest.raises(ValueError, match="non-empty 2-D"):
        disc_dilate(np.ones(10, np.uint8), np.array([1], np.int32))
    with pytest.raises(ValueError, match="out of range"):
        disc_dilate(np.ones((1, 30000), np.uint8), np.array([1], np.int32))
