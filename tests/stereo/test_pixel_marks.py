"""The image kernels of csrc/pixel_marks.c (pixel marks, edge profiles, measured pixels, label areas) against their
numpy formulations, and their bad input."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.stereo.kernels import edge_profiles, label_areas, mark_pixels, measured_pixels


def _numpy_marks(
    pixels: np.ndarray, disparity: np.ndarray, index: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The rule as numpy passes (cellctl.vision.sole_region._marked before the kernel)."""
    height, width = shape
    with np.errstate(invalid="ignore"):
        x, y = np.round(np.take(pixels, index, axis=0)).astype(np.int64).T
        xr = np.round(np.take(pixels[:, 0], index) - disparity[index]).astype(np.int64)
    marked = []
    for columns in (x, xr):
        inside = (columns >= 0) & (columns < width) & (y >= 0) & (y < height)
        image = np.zeros((height, width), np.uint8)
        image[y[inside], columns[inside]] = 1
        marked.append(image)
    return marked[0], marked[1]


def _points(rng: np.random.Generator, n: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixels over and beyond the image, a quarter of them on exact halves (the rounding's ties), a few NaN."""
    height, width = shape
    pixels = np.column_stack([rng.uniform(-3, width + 3, n), rng.uniform(-3, height + 3, n)])
    halves = rng.random(n) < 0.25
    pixels[halves] = np.floor(pixels[halves]) + 0.5
    disparity = rng.uniform(0, 12, n)
    disparity[rng.random(n) < 0.25] = np.floor(disparity[:1]) + 0.5
    pixels[rng.integers(0, n, 5), rng.integers(0, 2, 5)] = np.nan
    disparity[rng.integers(0, n, 5)] = np.nan
    return pixels, disparity


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_marks_match_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape = (37, 53)
    pixels, disparity = _points(rng, 4000, shape)
    index = np.sort(rng.choice(len(pixels), 1500, replace=False))
    expected = _numpy_marks(pixels, disparity, index, shape)
    left, right = mark_pixels(pixels, disparity, index, shape)
    assert right is not None
    assert np.array_equal(left, expected[0]) and np.array_equal(right, expected[1])
    assert 0 < np.count_nonzero(left) < left.size  # the test sees marked and unmarked pixels
    # All points (no index) and no right image.
    everything, none = mark_pixels(pixels, None, None, shape)
    assert none is None
    assert np.array_equal(everything, _numpy_marks(pixels, disparity, np.arange(len(pixels)), shape)[0])


def test_rounds_halves_to_even() -> None:
    pixels = np.array([[0.5, 0.0], [1.5, 1.0], [2.5, 1.5], [-0.5, 2.0], [3.49999, 0.0]])
    left, _ = mark_pixels(pixels, None, None, (3, 5))
    assert np.argwhere(left).tolist() == [[0, 0], [0, 3], [1, 2], [2, 0], [2, 2]]


def test_empty_index_and_cloud() -> None:
    left, right = mark_pixels(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64), (2, 2))
    assert right is not None and not left.any() and not right.any()


def test_bad_input_is_refused() -> None:
    pixels, disparity = np.zeros((4, 2)), np.zeros(4)
    with pytest.raises(ValueError, match="outside its array"):
        mark_pixels(pixels, disparity, np.array([0, 4]), (2, 2))
    with pytest.raises(ValueError, match="outside its array"):
        mark_pixels(pixels, disparity, np.array([-1]), (2, 2))
    with pytest.raises(ValueError, match="N x 2"):
        mark_pixels(np.zeros((4, 3)), disparity, None, (2, 2))
    with pytest.raises(ValueError, match="disparity"):
        mark_pixels(pixels, np.zeros(3), None, (2, 2))
    with pytest.raises(ValueError, match="must have pixels"):
        mark_pixels(pixels, disparity, None, (0, 2))
    with pytest.raises(ValueError, match="out of range"):
        mark_pixels(pixels, disparity, None, (1 << 21, 2))
    with pytest.raises(ValueError, match="1-D"):
        mark_pixels(pixels, disparity, np.zeros((2, 2), np.int64), (2, 2))


def _numpy_profiles(
    pixel: np.ndarray, changed: np.ndarray, level: np.ndarray | None, first_out: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The step rule as numpy passes (cellctl.vision.edge_checks.edge_offset_pair before the kernel)."""
    n, k = pixel.shape[:2]
    px = pixel.reshape(-1, 2)
    height, width = changed.shape
    ok = (px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)
    flat = np.zeros(len(px), bool)
    flat[ok] = changed[px[ok, 1], px[ok, 0]]
    known, value = ok.reshape(n, k), flat.reshape(n, k)
    if level is not None:
        known &= ~(value & level & (np.arange(k) >= first_out)[None, :])
    on, off = value & known, ~value & known
    before = np.concatenate([np.zeros((n, 1)), np.cumsum(off, axis=1)], axis=1)
    after = np.concatenate([np.cumsum(on[:, ::-1], axis=1)[:, ::-1], np.zeros((n, 1))], axis=1)
    misfit = before + after
    inner, outer = np.argmin(misfit, axis=1), k - np.argmin(misfit[:, ::-1], axis=1)
    return inner, outer, misfit[np.arange(n), inner], known.sum(axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_edge_profiles_match_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    shape, n, k = (40, 60), 300, 33
    # Steps along the profiles with noise, some profiles partly off the mask, ties between equal misfits.
    changed = np.zeros(shape, bool)
    changed[:, : int(rng.integers(10, 50))] = True
    changed ^= rng.random(shape) < rng.uniform(0.0, 0.3)
    start = np.column_stack([rng.integers(-20, 70, n), rng.integers(-5, 45, n)])
    pixel = start[:, None, :] + np.arange(k)[None, :, None] * np.array([-1, 0])[None, None, :]
    level = rng.random((n, k)) < 0.3
    for excused in (None, level):
        expected = _numpy_profiles(pixel, changed, excused, 17)
        got = edge_profiles(pixel, changed, excused, 17)
        for e, g in zip(expected, got, strict=True):
            np.testing.assert_array_equal(g, e)
    assert np.any(got[0] != got[1])  # ties do occur: the innermost and outermost differ somewhere


def test_edge_profiles_bad_input_is_refused() -> None:
    pixel, changed = np.zeros((3, 5, 2), np.int64), np.zeros((4, 4), bool)
    with pytest.raises(ValueError, match="n x k x 2"):
        edge_profiles(np.zeros((3, 5)), changed, None, 2)
    with pytest.raises(ValueError, match="non-empty image"):
        edge_profiles(pixel, np.zeros((0, 4), bool), None, 2)
    with pytest.raises(ValueError, match="level"):
        edge_profiles(pixel, changed, np.zeros((3, 4), bool), 2)
    with pytest.raises(ValueError, match="out of range"):
        edge_profiles(pixel, changed, None, 6)
    with pytest.raises(ValueError, match="out of range"):
        edge_profiles(pixel, changed, None, -1)


@pytest.mark.parametrize("seed", [0, 1])
def test_measured_pixels_match_numpy(seed: int) -> None:
    """The cloud's measured pixels as numpy gathered them (cellctl.vision.cloud before the kernel)."""
    rng = np.random.default_rng(seed)
    shape, invalid, scale, origin, shift = (23, 41), -32768, 16.0, (7, 3), 150
    fixed = rng.integers(0, 3000, shape).astype(np.int16)
    fixed[rng.random(shape) < 0.3] = invalid
    texture = rng.uniform(0.0, 1.0, shape).astype(np.float32)
    texture[rng.random(shape) < 0.1] = 0.5  # the threshold itself counts as texture
    measured = (fixed != invalid) & (texture >= 0.5)
    flat = np.flatnonzero(measured)
    ys = flat // shape[1]
    xs = flat - ys * shape[1]
    disparity = fixed.ravel()[flat] / scale + shift
    pixels = np.column_stack([xs + origin[0], ys + origin[1]]).astype(np.float64)
    got = measured_pixels(fixed, texture, invalid, 0.5, origin, scale, shift)
    for g, e in zip(got, (flat, pixels, np.column_stack([pixels, disparity]), disparity), strict=True):
        assert g.dtype == e.dtype and np.array_equal(g, e)
    assert 0 < len(flat) < fixed.size
    none = measured_pixels(np.full(shape, invalid, np.int16), texture, invalid, 0.5, origin, scale, shift)
    assert [a.shape for a in none] == [(0,), (0, 2), (0, 3), (0,)]


def test_measured_pixels_bad_input_is_refused() -> None:
    fixed, texture = np.zeros((4, 5), np.int16), np.ones((4, 5), np.float32)
    with pytest.raises(ValueError, match="one non-empty image size"):
        measured_pixels(fixed, np.ones((4, 4), np.float32), -1, 0.5, (0, 0), 16.0, 0)
    with pytest.raises(ValueError, match="one non-empty image size"):
        measured_pixels(np.zeros((0, 5), np.int16), np.ones((0, 5), np.float32), -1, 0.5, (0, 0), 16.0, 0)
    with pytest.raises(ValueError, match="out of range"):
        measured_pixels(fixed, texture, -1, 0.5, (0, 0), 0.0, 0)


def test_label_areas_are_bincounts() -> None:
    rng = np.random.default_rng(4)
    for count in (1, 2, 7, 300):
        labels = rng.integers(0, count, (37, 29)).astype(np.int32)
        np.testing.assert_array_equal(label_areas(labels, count), np.bincount(labels.ravel(), minlength=count))
    labels = np.zeros((3, 3), np.int32)
    labels[1, 1] = 5
    with pytest.raises(ValueError, match="outside its array"):
        label_areas(labels, 5)
    with pytest.raises(ValueError, match="at least 1"):
        label_areas(labels, 0)
