"""The pixel-marking kernel (csrc/pixel_marks.c) against its numpy formulation, and its bad input."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.stereo.kernels import mark_pixels


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
