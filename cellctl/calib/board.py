"""The calibration target: a checkerboard's geometry and its inner corners found in an image."""

from __future__ import annotations

import re
from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.images import grey

_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)


@dataclass(frozen=True)
class Checkerboard:
    """A printed checkerboard: counts of inner corners along its width and height, square side in mm."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"a checkerboard needs at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if self.cols == self.rows:
            # A square corner grid has no defined orientation: OpenCV may number its corners rotated by 90
            # degrees in one camera and not in the other, which corrupts the stereo calibration.
            raise ValueError(
                f"use a board with different inner-corner counts along each side, not {self.cols}x{self.rows}"
            )
        if not self.square_mm > 0:
            raise ValueError(f"the square size must be positive, got {self.square_mm} mm")

    @classmethod
    def from_spec(cls, spec: str, square_mm: float) -> Checkerboard:
        """A board from "COLSxROWS" inner corners, e.g. "9x6", and its square size."""
        match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", spec)
        if not match:
            raise ValueError(f"board {spec!r} is not COLSxROWS inner corners, e.g. 9x6 for a board of 10x7 squares")
        return cls(int(match.group(1)), int(match.group(2)), float(square_mm))

    @property
    def pattern_size(self) -> tuple[int, int]:
        """(cols, rows) as OpenCV's chessboard functions take it."""
        return (self.cols, self.rows)

    def object_points(self) -> np.ndarray:
        """Inner-corner positions on the board plane (z = 0), mm, in OpenCV's detection order."""
        grid = np.mgrid[0 : self.cols, 0 : self.rows].T.reshape(-1, 2)
        points = np.zeros((self.cols * self.rows, 3), np.float32)
        points[:, :2] = grid * self.square_mm
        return points

    def outline(self, margin_squares: float = 1.0) -> np.ndarray:
        """Corners of the printed area (squares plus a white margin), mm, on the board plane."""
        lo = -(1.0 + margin_squares) * self.square_mm
        hi_x = (self.cols + margin_squares) * self.square_mm
        hi_y = (self.rows + margin_squares) * self.square_mm
        return np.array([[lo, lo, 0], [hi_x, lo, 0], [hi_x, hi_y, 0], [lo, hi_y, 0]], np.float64)


def find_corners(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """Sub-pixel inner corners of `board` in `image` (N x 2, canonical order), or None if not all found."""
    gray = grey(image)
    # No CALIB_CB_NORMALIZE_IMAGE: the adaptive threshold already copes with uneven light, and with
    # normalisation a 1280x1024 image without a complete board takes seconds to give up on instead of 0.3 s.
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(gray, board.pattern_size, flags=flags)
    if not found:
        return None
    grid = corners.reshape(board.rows, board.cols, 2)
    # The refinement window must stay inside one square: a quarter of the smallest corner spacing.
    spacing = min(np.linalg.norm(np.diff(grid, axis=axis), axis=2).min() for axis in (0, 1))
    half = int(np.clip(spacing / 4, 2, 11))
    corners = cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)
    return _canonical_order(gray, corners.reshape(-1, 2), board)


def _canonical_order(gray: np.ndarray, corners: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Number the corners the same way in both cameras, tied to the physical board.

    OpenCV may start the numbering at either end of the board; if the left and right images disagree the
    stereo calibration is garbage. Convention: the board's x axis runs along the rows to the image's right
    of its y axis (the board seen from the front), and the square between the first four corners is dark.
    """
    grid = corners.reshape(board.rows, board.cols, 2)
    x_axis, y_axis = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    if x_axis[0] * y_axis[1] - x_axis[1] * y_axis[0] < 0:
        grid = grid[::-1]  # mirrored numbering: count the rows the other way
    if (board.cols + board.rows) % 2 == 1:
        first, last = grid[:2, :2].reshape(-1, 2).mean(axis=0), grid[-2:, -2:].reshape(-1, 2).mean(axis=0)
        if _grey_at(gray, first) > _grey_at(gray, last):
            grid = grid[::-1, ::-1]
    elif np.dot(grid[-1, -1] - grid[0, 0], (1.0, 1.0)) < 0:
        # With both square counts even or both odd the board looks the same turned by 180 degrees, so
        # colour cannot tell the ends apart: start near the image's top-left in both cameras instead.
        grid = grid[::-1, ::-1]
    return np.ascontiguousarray(grid.reshape(-1, 2), dtype=np.float32)


def _grey_at(gray: np.ndarray, point: np.ndarray) -> float:
    x, y = (int(round(v)) for v in point)
    return float(gray[max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2].mean())
