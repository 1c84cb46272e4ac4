"""The measurement's hot loops in C (csrc/cloud_kernels.c), behind numpy-level functions.

They sit behind the stereo package because it is the one door to the compiled core; the vision layer
(cellctl.vision.outliers, cellctl.vision.subpixel) calls them and keeps the numpy reference in its tests.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.stereo._core import ffi, lib

_ERRORS = {
    lib.CK_ERR_NULL: "a required array is missing",
    lib.CK_ERR_SIZE: "a count or grid size is out of range",
    lib.CK_ERR_RANGE: "an index lies outside its array",
}


# Every kernel runs on all the threads OpenMP offers (the matcher's default too); results are bit-identical for
# any thread count because each output element is computed whole by one thread (csrc/cloud_kernels.h).
ALL_THREADS = 0


def _threads(threads: int) -> int:
    if not 0 <= threads <= 256:
        raise ValueError(f"threads must be between 0 (all) and 256, got {threads}")
    return threads


def _check(rc: int, what: str) -> None:
    if rc != lib.CK_OK:
        raise ValueError(f"{what}: {_ERRORS.get(rc, f'error {rc}')}")


def _ptr(kind: str, array: np.ndarray):  # noqa: ANN202 - a cffi pointer
    return ffi.cast(kind, ffi.from_buffer(array))


def neighbour_means(
    grid: np.ndarray, at: np.ndarray, spacing_mm: np.ndarray, offsets: np.ndarray, threads: int = ALL_THREADS
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: mean distance to its 19 nearest block neighbours (float32) and whether that is exact (bool).

    grid: 3 x H x W float32 points (NaN where none); at: flat index of each point in one plane, at least 3 px
    inside the grid; spacing_mm: mm between pixels at each point; offsets: 36 x 2 (dx, dy), the 20 within
    2.3 px first (cellctl.vision.outliers defines the rule); threads: OpenMP threads (0: all), the same
    result on any number.
    """
    count, _kept, leading = _grid_arguments(grid, at, spacing_mm)
    offsets = np.ascontiguousarray(offsets, np.int32)
    if offsets.shape != (36, 2):
        raise ValueError(f"offsets must be 36 x 2, got shape {offsets.shape}")
    mean = np.empty(count, np.float32)
    exact = np.empty(count, np.uint8)
    rc = lib.ck_neighbour_means(
        *leading,
        _ptr("const int32_t *", offsets),
        _ptr("float *", mean),
        _ptr("uint8_t *", exact),
        _threads(threads),
    )
    _check(rc, "neighbour means")
    return mean, exact.astype(bool)


def window_means(
    grid: np.ndarray,
    at: np.ndarray,
    spacing_mm: np.ndarray,
    halves: tuple[int, ...],
    threads: int = ALL_THREADS,
) -> tuple[np.ndarray, np.ndarray]:
    """Per point: mean distance to its 19 nearest in the narrowest of the windows (2 half + 1 px square) that
    settles it, each capped at half + 1 spacings (float32), and whether one did (bool; else the widest one's).

    grid: 3 x H x W float32 points (NaN where none); at: flat index of each point in one plane, at least the
    widest half inside the grid; spacing_mm: mm between pixels at each point; halves: increasing window halves
    (cellctl.vision.outliers defines the rule); threads: OpenMP threads (0: all), the same result on any number.
    """
    count, _kept, leading = _grid_arguments(grid, at, spacing_mm)
    half = np.ascontiguousarray(halves, np.int32)
    if half.ndim != 1:
        raise ValueError(f"halves must be a sequence of window halves, got shape {half.shape}")
    mean = np.empty(count, np.float32)
    settled = np.empty(count, np.uint8)
    rc = lib.ck_window_means(
        *leading,
        _ptr("const int32_t *", half),
        len(half),
        _ptr("float *", mean),
        _ptr("uint8_t *", settled),
        _threads(threads),
    )
    _check(rc, "window means")
    return mean, settled.astype(bool)


def _starts(starts: np.ndarray) -> tuple[np.ndarray, int, int]:
    starts = np.ascontiguousarray(starts, np.int64)
    if starts.ndim != 1 or len(starts) < 1:
        raise ValueError("patch offsets (starts) must be a non-empty 1-D array")
    return starts, len(starts) - 1, int(starts[-1])


def _per_pixel(pixels: int, *arrays: np.ndarray) -> list[np.ndarray]:
    out = [np.ascontiguousarray(a, np.float64) for a in arrays]
    if any(a.shape != (pixels,) for a in out):
        raise ValueError(f"per-pixel arrays must have the {pixels} pixels the patch offsets end at")
    return out


def patch_shift(
    starts: np.ndarray,
    params: np.ndarray,
    x: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    threads: int = ALL_THREADS,
) -> np.ndarray:
    """x - (a + b dx + c dy) per pixel (float32), (a, b, c) = params (K x 3) of its patch; pixels stored patch
    after patch, patch k's are [starts[k], starts[k + 1])."""
    starts, count, pixels = _starts(starts)
    params = np.ascontiguousarray(params, np.float64)
    if params.shape != (count, 3):
        raise ValueError(f"patch shift: params must be {count} x 3, got {params.shape}")
    x = np.ascontiguousarray(x, np.float32)
    dx, dy = _per_pixel(pixels, dx, dy)
    if x.shape != (pixels,):
        raise ValueError(f"patch shift: x must have {pixels} pixels, got {x.shape}")
    out = np.empty(pixels, np.float32)
    rc = lib.ck_patch_shift(
        count,
        _ptr("const int64_t *", starts),
        _ptr("const double *", params),
        _ptr("const float *", x),
        _ptr("const double *", dx),
        _ptr("const double *", dy),
        _ptr("float *", out),
        _threads(threads),
    )
    _check(rc, "patch shift")
    return out


def patch_step(
    starts: np.ndarray,
    l_dev: np.ndarray,
    l_energy: np.ndarray,
    right: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    threads: int = ALL_THREADS,
) -> np.ndarray:
    """One Gauss-Newton step (K x 3) of affine disparity patches (cellctl.vision.subpixel).

    starts: K + 1 offsets, patch k's pixels are [starts[k], starts[k + 1]); per pixel (N): l_dev, dx, dy, and
    right (N x 2 float32: the right image and its x gradient where the patch plane puts the pixel); per
    patch (K): l_energy.
    """
    starts, count, pixels = _starts(starts)
    l_dev, dx, dy = _per_pixel(pixels, l_dev, dx, dy)
    right = np.ascontiguousarray(right, np.float32)
    if right.shape != (pixels, 2):
        raise ValueError(f"patch step: right must be {pixels} x 2 (value, gradient), got {right.shape}")
    energy = np.ascontiguousarray(l_energy, np.float64)
    if energy.shape != (count,):
        raise ValueError(f"patch step: l_energy must have one value per patch ({count}), got {energy.shape}")
    step = np.empty((count, 3), np.float64)
    rc = lib.ck_patch_step(
        count,
        _ptr("const int64_t *", starts),
        _ptr("const double *", l_dev),
        _ptr("const double *", energy),
        _ptr("const float *", right),
        _ptr("const double *", dx),
        _ptr("const double *", dy),
        _ptr("double *", step),
        _threads(threads),
    )
    _check(rc, "patch step")
    return step


def points_in_polygon(polygon: np.ndarray, points: np.ndarray) -> np.ndarray:
    """cv2.pointPolygonTest(polygon as float32, point, False) for each point (M x 2, sorted by y): 1 inside,
    -1 outside, 0 on the boundary (int8, M), in one call."""
    polygon = np.ascontiguousarray(np.asarray(polygon).reshape(-1, 2), np.float32)
    points = np.ascontiguousarray(np.asarray(points).reshape(-1, 2), np.float32)
    out = np.empty(len(points), np.int8)
    rc = lib.ck_points_in_polygon(
        _ptr("const float *", polygon), len(polygon), _ptr("const float *", points), len(points), _ptr("int8_t *", out)
    )
    _check(rc, "points in polygon (points sorted by y)")
    return out


def patch_sample(
    starts: np.ndarray,
    params: np.ndarray,
    x: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    rows: np.ndarray,
    image: np.ndarray,
    threads: int = ALL_THREADS,
    simd: bool = True,
) -> np.ndarray:
    """A two-channel image (H x W x 2 float32) sampled bicubically where each pixel's patch plane puts it
    (`patch_shift`'s x, on the pixel's row `rows`): pixels x 2 float32, to ~2e-6 of what cv2.remap (INTER_CUBIC,
    BORDER_REPLICATE) gives there. simd: the AVX2 kernel where the CPU has it (the same bits as the scalar one,
    False)."""
    starts, count, pixels = _starts(starts)
    params = np.ascontiguousarray(params, np.float64)
    if params.shape != (count, 3):
        raise ValueError(f"patch sample: params must be {count} x 3, got {params.shape}")
    x = np.ascontiguousarray(x, np.float32)
    dx, dy = _per_pixel(pixels, dx, dy)
    rows = np.ascontiguousarray(rows, np.int32)
    if x.shape != (pixels,) or rows.shape != (pixels,):
        raise ValueError(f"patch sample: x and rows must have {pixels} pixels, got {x.shape} and {rows.shape}")
    image = np.ascontiguousarray(image, np.float32)
    if image.ndim != 3 or image.shape[2] != 2:
        raise ValueError(f"patch sample: image must be H x W x 2, got shape {image.shape}")
    out = np.empty((pixels, 2), np.float32)
    rc = lib.ck_patch_sample(
        count,
        _ptr("const int64_t *", starts),
        _ptr("const double *", params),
        _ptr("const float *", x),
        _ptr("const double *", dx),
        _ptr("const double *", dy),
        _ptr("const int32_t *", rows),
        _ptr("const float *", image),
        image.shape[0],
        image.shape[1],
        _ptr("float *", out),
        int(simd),
        _threads(threads),
    )
    _check(rc, "patch sample")
    return out


def _grid_arguments(
    grid: np.ndarray, at: np.ndarray, spacing_mm: np.ndarray
) -> tuple[int, tuple[np.ndarray, ...], tuple[Any, ...]]:
    """The pixel-grid kernels' common arguments as C wants them: each pixel's x y z side by side (one cache
    line per neighbour instead of three), the points' flat indices, and a spacing per point.

    Returns the number of points, the arrays C reads (keep them alive across the call) and the kernels'
    leading arguments: points, grid height and width, indices, count, spacings."""
    if grid.ndim != 3 or grid.shape[0] != 3:
        raise ValueError(f"grid must be 3 x H x W, got shape {grid.shape}")
    points = np.ascontiguousarray(np.moveaxis(grid, 0, -1), np.float32)
    at = np.ascontiguousarray(at, np.int64)
    spacing = np.ascontiguousarray(np.broadcast_to(spacing_mm, at.shape), np.float64)
    leading = (
        _ptr("const float *", points),
        grid.shape[1],
        grid.shape[2],
        _ptr("const int64_t *", at),
        len(at),
        _ptr("const double *", spacing),
    )
    return len(at), (points, at, spacing), leading


def _raster_points(xy: np.ndarray) -> tuple[np.ndarray, int]:
    """Points (N x 2 or more columns, x and y first) as float64 rows C can read in place, and their stride."""
    xy = np.asarray(xy, np.float64)
    if xy.ndim != 2 or xy.shape[1] < 2:
        raise ValueError(f"points must be N x 2 (x, y first), got shape {xy.shape}")
    if len(xy) == 0:
        return xy, 2
    if xy.strides[1] != 8 or xy.strides[0] % 8 or xy.strides[0] < 16:
        xy = np.ascontiguousarray(xy[:, :2])
    return xy, xy.strides[0] // 8


def _raster_args(xy: np.ndarray, origin: tuple[float, float], cell_mm: float) -> tuple[np.ndarray, tuple[Any, ...]]:
    """The points as C reads them (keep the array alive across the call) and the raster kernels' leading
    arguments: points, count, row stride, origin x and y, cell size."""
    xy, stride = _raster_points(xy)
    # The rows may be a view into a wider array (x y z): the pointer to its first element, kept alive by xy
    # (no points: any valid pointer, nothing is read).
    pointer = ffi.cast("const double *", (xy if len(xy) else _NO_POINTS).ctypes.data)
    return xy, (pointer, len(xy), stride, float(origin[0]), float(origin[1]), float(cell_mm))


_NO_POINTS = np.zeros(2)


def cell_counts(xy: np.ndarray, origin: tuple[float, float], cell_mm: float, shape: tuple[int, int]) -> np.ndarray:
    """Points (N x 2, table mm) per cell of a raster of `shape` whose cell (0, 0) has its corner at `origin`
    (float32 counts; cell = floor((x - x0) / cell_mm) in double as numpy takes it; points off it count nowhere)."""
    xy, leading = _raster_args(xy, origin, cell_mm)
    rows, cols = shape
    if rows < 1 or cols < 1:
        raise ValueError(f"the raster must have cells, got shape {shape}")
    out = np.empty((rows, cols), np.float32)
    rc = lib.ck_cell_counts(*leading, rows, cols, _ptr("float *", out))
    _check(rc, "cell counts")
    return out


def cells_marked(xy: np.ndarray, origin: tuple[float, float], cell_mm: float, mask: np.ndarray) -> np.ndarray:
    """Whether each point's cell (as `cell_counts` finds it) is non-zero in `mask` (uint8 raster): bool, N."""
    xy, leading = _raster_args(xy, origin, cell_mm)
    mask = np.ascontiguousarray(mask, np.uint8)
    if mask.ndim != 2 or mask.size == 0:
        raise ValueError(f"mask must be a non-empty 2-D raster, got shape {mask.shape}")
    out = np.empty(max(len(xy), 1), np.uint8)
    rc = lib.ck_cells_marked(
        *leading, _ptr("const uint8_t *", mask), mask.shape[0], mask.shape[1], _ptr("uint8_t *", out)
    )
    _check(rc, "cells marked")
    return out[: len(xy)].view(bool)


def disc_dilate(mask: np.ndarray, half_widths: np.ndarray, of_zero: bool = False, invert: bool = False) -> np.ndarray:
    """Binary dilation (uint8 0/1) of a uint8 raster's non-zero cells (of its zero cells with of_zero) by a disc
    of centred runs: row d (-reach..reach) of the disc spans columns -half_widths[d + reach]..half_widths[d +
    reach]; cells off the raster are no sources. invert: the complement (an erosion, with of_zero, as cv2
    erodes with its default border)."""
    mask = np.ascontiguousarray(mask, np.uint8)
    half = np.ascontiguousarray(half_widths, np.int32)
    if mask.ndim != 2 or mask.size == 0:
        raise ValueError(f"mask must be a non-empty 2-D raster, got shape {mask.shape}")
    if half.ndim != 1 or len(half) % 2 != 1:
        raise ValueError(f"the disc needs an odd number of runs, got shape {half.shape}")
    out = np.empty(mask.shape, np.uint8)
    scratch = np.empty(mask.shape, np.int16)
    rc = lib.ck_disc_dilate(
        _ptr("const uint8_t *", mask),
        mask.shape[0],
        mask.shape[1],
        int(of_zero),
        _ptr("const int32_t *", half),
        len(half) // 2,
        int(invert),
        _ptr("uint8_t *", out),
        _ptr("int16_t *", scratch),
    )
    _check(rc, "disc dilation")
    return out


def mark_pixels(
    pixels: np.ndarray,
    disparity: np.ndarray | None,
    index: np.ndarray | None,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray | None]:
    """The left (and right) rectified images (uint8 0/1, `shape` rows x columns) with 1 at the pixels of the
    points `index` (all points if None): left at (rint(x), rint(y)) of `pixels` (N x 2 x y), right at
    (rint(x - disparity), rint(y)) (no right image without `disparity`); rint rounds halves to even, as np.round.
    Points whose pixel is off an image are left out of it (csrc/pixel_marks.h)."""
    pixels = np.ascontiguousarray(pixels, np.float64)
    if pixels.ndim != 2 or pixels.shape[1] != 2:
        raise ValueError(f"pixels must be N x 2, got shape {pixels.shape}")
    n = len(pixels)
    rows, cols = shape
    if rows < 1 or cols < 1:
        raise ValueError(f"the images must have pixels, got shape {shape}")
    if disparity is not None:
        disparity = np.ascontiguousarray(disparity, np.float64)
        if disparity.shape != (n,):
            raise ValueError(f"disparity must have the {n} points' values, got shape {disparity.shape}")
    if index is not None:
        index = np.ascontiguousarray(index, np.int64)
        if index.ndim != 1:
            raise ValueError(f"index must be 1-D, got shape {index.shape}")
    left = np.zeros((rows, cols), np.uint8)
    right = None if disparity is None else np.zeros((rows, cols), np.uint8)
    rc = lib.pm_mark_pixels(
        _ptr("const double *", pixels),
        ffi.NULL if disparity is None else _ptr("const double *", disparity),
        n,
        ffi.NULL if index is None else _ptr("const int64_t *", index),
        0 if index is None else len(index),
        rows,
        cols,
        _ptr("uint8_t *", left),
        ffi.NULL if right is None else _ptr("uint8_t *", right),
    )
    _check(rc, "pixel marks")
    return left, right


def edge_profiles(
    pixel: np.ndarray, changed: np.ndarray, level: np.ndarray | None, first_out: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The change mask's step along profiles (csrc/pixel_marks.h, pm_edge_profiles): per profile (row of
    `pixel`, n x k x 2 integer x y) the first and the last step position j (0..k) of the least misfit, that misfit
    and the number of known samples (int32 each). Samples off `changed` (bool or 0/1 image) are unknown, and so
    are changed ones at or after sample `first_out` where `level` (n x k bool, or None) is set."""
    pixel = np.ascontiguousarray(pixel, np.int64)
    if pixel.ndim != 3 or pixel.shape[2] != 2 or pixel.shape[1] < 1:
        raise ValueError(f"pixel must be n x k x 2 (k >= 1), got shape {pixel.shape}")
    n, k = pixel.shape[:2]
    mask = (
        np.ascontiguousarray(changed).view(np.uint8)
        if changed.dtype == bool
        else np.ascontiguousarray(changed, np.uint8)
    )
    if mask.ndim != 2 or mask.size == 0:
        raise ValueError(f"changed must be a non-empty image, got shape {mask.shape}")
    excused = None
    if level is not None:
        excused = np.ascontiguousarray(level, bool).view(np.uint8)
        if excused.shape != (n, k):
            raise ValueError(f"level must be {n} x {k}, got shape {excused.shape}")
    inner, outer, misfit, known = (np.empty(max(n, 1), np.int32) for _ in range(4))
    rc = lib.pm_edge_profiles(
        _ptr("const int64_t *", pixel),
        n,
        k,
        _ptr("const uint8_t *", mask),
        mask.shape[0],
        mask.shape[1],
        ffi.NULL if excused is None else _ptr("const uint8_t *", excused),
        first_out,
        _ptr("int32_t *", inner),
        _ptr("int32_t *", outer),
        _ptr("int32_t *", misfit),
        _ptr("int32_t *", known),
    )
    _check(rc, "edge profiles")
    return inner[:n], outer[:n], misfit[:n], known[:n]


def measured_pixels(
    fixed: np.ndarray,
    texture: np.ndarray,
    invalid: int,
    min_texture: float,
    origin: tuple[int, int],
    scale: float,
    shift: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The measured pixels of the matcher's int16 map (not `invalid`, `texture` >= min_texture, float32 compare),
    in raster order (csrc/pixel_marks.h): their flat index in the map, their pixels (N x 2 x y, shifted by
    `origin`), the same with the disparity (N x 3, the reprojection's input) and the disparity fixed / scale +
    shift (N), float64."""
    fixed = np.ascontiguousarray(fixed, np.int16)
    texture = np.ascontiguousarray(texture, np.float32)
    if fixed.ndim != 2 or fixed.size == 0 or texture.shape != fixed.shape:
        raise ValueError(f"fixed and texture must be one non-empty image size, got {fixed.shape} and {texture.shape}")
    rows, cols = fixed.shape
    count = ffi.new("int64_t *")
    _check(
        lib.pm_count_measured(
            _ptr("const int16_t *", fixed), _ptr("const float *", texture), rows, cols, invalid, min_texture, count
        ),
        "measured pixels",
    )
    n = int(count[0])
    flat = np.empty(n, np.int64)
    pixels, pixel_disparity, disparity = np.empty((n, 2)), np.empty((n, 3)), np.empty(n)
    rc = lib.pm_gather_measured(
        _ptr("const int16_t *", fixed),
        _ptr("const float *", texture),
        rows,
        cols,
        invalid,
        min_texture,
        int(origin[0]),
        int(origin[1]),
        float(scale),
        float(shift),
        n,
        _ptr("int64_t *", flat),
        _ptr("double *", pixels),
        _ptr("double *", pixel_disparity),
        _ptr("double *", disparity),
    )
    _check(rc, "measured pixels")
    return flat, pixels, pixel_disparity, disparity


def label_areas(labels: np.ndarray, count: int) -> np.ndarray:
    """Cells per label 0..count-1 of a label image (int32, as cv2.connectedComponents gives it): np.bincount's
    int64 counts in one pass, without its copy of the labels to intp (csrc/pixel_marks.h)."""
    labels = np.ascontiguousarray(labels, np.int32)
    if count < 1:
        raise ValueError(f"count must be at least 1 (the background), got {count}")
    areas = np.empty(count, np.int64)
    rc = lib.pm_label_areas(_ptr("const int32_t *", labels), labels.size, count, _ptr("int64_t *", areas))
    _check(rc, "label areas")
    return areas
