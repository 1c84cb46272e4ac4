"""The surface's point grid: points of a plane sorted into square cells, radius queries and medians in C
(csrc/cloud_kernels.c: ck_grid_build, ck_grid_radius, ck_grid_radius_medians, ck_cell_upper_medians)."""

from __future__ import annotations

import numpy as np

from cellctl.stereo._core import ffi, lib
from cellctl.stereo.kernels import _check, _ptr, _threads


def _grid_shape(x: np.ndarray, y: np.ndarray, x0: float, y0: float, cell: float) -> tuple[int, int]:
    """Rows and columns from (x0, y0) just covering the points (1 x 1 when there are none)."""
    if not len(x):
        return 1, 1
    return int(np.floor((y.max() - y0) / cell)) + 1, int(np.floor((x.max() - x0) / cell)) + 1


def _build(x: np.ndarray, y: np.ndarray, corner: tuple[float, float, float, int, int]) -> tuple:
    """The points' order cell by cell and each cell's start in it (cols x rows + 1)."""
    x0, y0, cell, cols, rows = corner
    order = np.empty(len(x), np.int64)
    starts = np.empty(cols * rows + 1, np.int64)
    rc = lib.ck_grid_build(
        _ptr("const double *", x), _ptr("const double *", y), len(x), x0, y0, cell, cols, rows,
        _ptr("int64_t *", order), _ptr("int64_t *", starts),
    )  # fmt: skip
    _check(rc, "point grid")
    return order, starts


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
        self.rows, self.cols = (int(n) for n in (shape or _grid_shape(x, y, self.x0, self.y0, self.cell)))
        self.count = len(x)
        self.order, self.starts = _build(x, y, self._corner())
        self.gx, self.gy = x[self.order], y[self.order]
        self.gz: np.ndarray | None = None
        if values is not None:
            values = np.asarray(values, np.float64)
            if values.shape != (len(x),) or not np.all(np.isfinite(values)):
                raise ValueError("point grid: values must be finite, one per point")
            self.gz = values[self.order]

    def _corner(self) -> tuple[float, float, float, int, int]:
        return self.x0, self.y0, self.cell, self.cols, self.rows

    def _queries(self, xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        if not radius >= 0:
            raise ValueError(f"radius must not be negative, got {radius}")
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])

    def _radius(self, qx: np.ndarray, qy: np.ndarray, radius: float, offsets: np.ndarray | None) -> tuple:
        counts = np.empty(len(qx), np.int64)
        found = None if offsets is None else np.empty(int(offsets[-1]), np.int64)
        rc = lib.ck_grid_radius(
            _ptr("const double *", self.gx), _ptr("const double *", self.gy), _ptr("const int64_t *", self.order),
            _ptr("const int64_t *", self.starts), *self._corner(), _ptr("const double *", qx),
            _ptr("const double *", qy), len(qx), float(radius), _ptr("int64_t *", counts),
            ffi.NULL if offsets is None else _ptr("const int64_t *", offsets),
            ffi.NULL if found is None else _ptr("int64_t *", found), self.threads,
        )  # fmt: skip
        _check(rc, "point grid radius")
        return counts, found

    def radius_counts(self, xy: np.ndarray, radius: float) -> np.ndarray:
        """How many points lie within `radius` of each query point (K x 2)."""
        return self._radius(*self._queries(xy, radius), radius, None)[0]

    def radius_members(self, xy: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Per query point (K x 2) how many points lie within `radius`, and those points (indices) query after
        query in one array (unordered within a query): for work done on all of them at once."""
        qx, qy = self._queries(xy, radius)
        counts = self._radius(qx, qy, radius, None)[0]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return counts, self._radius(qx, qy, radius, offsets)[1]

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
            _ptr("const double *", self.gx), _ptr("const double *", self.gy), _ptr("const double *", self.gz),
            _ptr("const int64_t *", self.starts), *self._corner(), _ptr("const double *", qx),
            _ptr("const double *", qy), len(qx), float(radius), _ptr("const int64_t *", offsets),
            _ptr("double *", scratch), _ptr("double *", medians), self.threads,
        )  # fmt: skip
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
            _ptr("const double *", self.gz), _ptr("const int64_t *", self.starts), self.rows * self.cols,
            _ptr("double *", scratch), _ptr("double *", out), self.threads,
        )  # fmt: skip
        _check(rc, "cell medians")
        return out.reshape(self.rows, self.cols)
