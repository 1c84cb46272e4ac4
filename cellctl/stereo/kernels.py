"""The measurement's hot loops in C (csrc/cloud_kernels.c), behind numpy-level functions.

They sit behind the stereo package because it is the one door to the compiled core; the vision layer
(cellctl.vision.outliers, cellctl.vision.subpixel) calls them and keeps the numpy reference in its tests.
"""

from __future__ import annotations

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
    if grid.ndim != 3 or grid.shape[0] != 3:
        raise ValueError(f"grid must be 3 x H x W, got shape {grid.shape}")
    # Each pixel's x y z side by side: one cache line per neighbour instead of three.
    points = np.ascontiguousarray(np.moveaxis(grid, 0, -1), np.float32)
    at = np.ascontiguousarray(at, np.int64)
    spacing = np.ascontiguousarray(np.broadcast_to(spacing_mm, at.shape), np.float64)
    offsets = np.ascontiguousarray(offsets, np.int32)
    if offsets.shape != (36, 2):
        raise ValueError(f"offsets must be 36 x 2, got shape {offsets.shape}")
    mean = np.empty(len(at), np.float32)
    exact = np.empty(len(at), np.uint8)
    rc = lib.ck_neighbour_means(
        _ptr("const float *", points),
        grid.shape[1],
        grid.shape[2],
        _ptr("const int64_t *", at),
        len(at),
        _ptr("const double *", spacing),
        _ptr("const int32_t *", offsets),
        _ptr("float *", mean),
        _ptr("uint8_t *", exact),
        _threads(threads),
    )
    _check(rc, "neighbour means")
    return mean, exact.astype(bool)


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


class PointGrid:
    """Points of a plane (N x 2, mm) sorted into square cells, for radius queries in C (csrc/cloud_kernels.c).

    The same neighbours as a k-d tree's radius search over (x, y, 0): squared distance in double below the
    radius squared; only the cells a query's radius reaches are read.
    """

    def __init__(
        self,
        xy: np.ndarray,
        cell_mm: float,
        values: np.ndarray | None = None,
        origin: tuple[float, float] | None = None,
        shape: tuple[int, int] | None = None,
        threads: int = 1,
    ) -> None:
        """values: one number per point (N, finite) whose medians `radius_medians` takes. origin (x, y of cell
        (0, 0)'s corner) and shape (rows, cols): a given raster's cells, which must hold every point (default:
        from the points' smallest x and y, just covering them). threads: for the queries (the same result on
        any number); one by default: a cycle's queries take a few ms and run beside the measurement's other
        threads, where an OpenMP team would wait for a core at its barrier."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if not cell_mm > 0:
            raise ValueError(f"cell size must be positive, got {cell_mm}")
        if not np.all(np.isfinite(xy)):
            raise ValueError("point grid: the points must be finite")
        x, y = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])
        self.cell = float(cell_mm)
        self.threads = _threads(threads)
        if origin is None:
            origin = (float(x.min()), float(y.min())) if len(x) else (0.0, 0.0)
        self.x0, self.y0 = float(origin[0]), float(origin[1])
        if shape is None:
            shape = (
                int(np.floor((y.max() - self.y0) / self.cell)) + 1 if len(y) else 1,
                int(np.floor((x.max() - self.x0) / self.cell)) + 1 if len(x) else 1,
            )
        self.rows, self.cols = int(shape[0]), int(shape[1])
        self.count = len(x)
        self.order = np.empty(len(x), np.int64)
        self.starts = np.empty(self.cols * self.rows + 1, np.int64)
        rc = lib.ck_grid_build(
            _ptr("const double *", x),
            _ptr("const double *", y),
            len(x),
            self.x0,
            self.y0,
            self.cell,
            self.cols,
            self.rows,
            _ptr("int64_t *", self.order),
            _ptr("int64_t *", self.starts),
        )
        _check(rc, "point grid")
        self.x, self.y = x, y
        self.gx, self.gy = x[self.order], y[self.order]
        self.gz: np.ndarray | None = None
        if values is not None:
            values = np.asarray(values, np.float64)
            if values.shape != (len(x),) or not np.all(np.isfinite(values)):
                raise ValueError("point grid: values must be finite, one per point")
            self.gz = values[self.order]

    def _queries(self, xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        if not radius >= 0:
            raise ValueError(f"radius must not be negative, got {radius}")
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])

    def _radius(self, qx: np.ndarray, qy: np.ndarray, radius: float, offsets: np.ndarray | None) -> tuple:
        counts = np.empty(len(qx), np.int64)
        found = None if offsets is None else np.empty(int(offsets[-1]), np.int64)
        rc = lib.ck_grid_radius(
            _ptr("const double *", self.gx),
            _ptr("const double *", self.gy),
            _ptr("const int64_t *", self.order),
            _ptr("const int64_t *", self.starts),
            self.x0,
            self.y0,
            self.cell,
            self.cols,
            self.rows,
            _ptr("const double *", qx),
            _ptr("const double *", qy),
            len(qx),
            float(radius),
            _ptr("int64_t *", counts),
            ffi.NULL if offsets is None else _ptr("const int64_t *", offsets),
            ffi.NULL if found is None else _ptr("int64_t *", found),
            self.threads,
        )
        _check(rc, "point grid radius")
        return counts, found

    def radius_counts(self, xy: np.ndarray, radius: float) -> np.ndarray:
        """How many points lie within `radius` of each query point (K x 2)."""
        return self._radius(*self._queries(xy, radius), radius, None)[0]

    def radius_indices(self, xy: np.ndarray, radius: float) -> list[np.ndarray]:
        """The points (indices) within `radius` of each query point, nearest first (ties by index), as a k-d
        tree's radius search orders them."""
        qx, qy = self._queries(xy, radius)
        counts = self._radius(qx, qy, radius, None)[0]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        _, found = self._radius(qx, qy, radius, offsets)
        out = []
        for k in range(len(qx)):
            index = found[offsets[k] : offsets[k + 1]]
            squared = (qx[k] - self.x[index]) ** 2 + (qy[k] - self.y[index]) ** 2
            out.append(index[np.lexsort((index, squared))])
        return out

    def radius_medians(self, xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Per query point (K x 2): how many points lie within `radius`, and the median of their values (NaN
        where none; the mean of the two middle values for an even count, as numpy's median)."""
        if self.gz is None:
            raise ValueError("point grid: built without values, no medians")
        qx, qy = self._queries(xy, radius)
        counts = self._radius(qx, qy, radius, None)[0]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        scratch = np.empty(int(offsets[-1]), np.float64)
        medians = np.empty(len(qx), np.float64)
        rc = lib.ck_grid_radius_medians(
            _ptr("const double *", self.gx),
            _ptr("const double *", self.gy),
            _ptr("const double *", self.gz),
            _ptr("const int64_t *", self.starts),
            self.x0,
            self.y0,
            self.cell,
            self.cols,
            self.rows,
            _ptr("const double *", qx),
            _ptr("const double *", qy),
            len(qx),
            float(radius),
            _ptr("const int64_t *", offsets),
            _ptr("double *", scratch),
            _ptr("double *", medians),
            self.threads,
        )
        _check(rc, "point grid medians")
        return counts, medians

    def cell_upper_medians(self) -> np.ndarray:
        """Per cell (rows x cols), the value of rank n // 2 among its n points' (the median for odd n, the upper
        middle one for even n); NaN in empty cells."""
        if self.gz is None:
            raise ValueError("point grid: built without values, no medians")
        scratch = np.empty(self.count, np.float64)
        out = np.empty(self.rows * self.cols, np.float64)
        rc = lib.ck_cell_upper_medians(
            _ptr("const double *", self.gz),
            _ptr("const int64_t *", self.starts),
            self.rows * self.cols,
            _ptr("double *", scratch),
            _ptr("double *", out),
            self.threads,
        )
        _check(rc, "cell medians")
        return out.reshape(self.rows, self.cols)


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
) -> np.ndarray:
    """A two-channel image (H x W x 2 float32) sampled bicubically where each pixel's patch plane puts it
    (`patch_shift`'s x, on the pixel's row `rows`): pixels x 2 float32, to ~2e-6 of what cv2.remap (INTER_CUBIC,
    BORDER_REPLICATE) gives there."""
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
        _threads(threads),
    )
    _check(rc, "patch sample")
    return out
