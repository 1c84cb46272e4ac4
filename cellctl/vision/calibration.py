"""Stereo calibration of the camera pair and the rectification it implies.

A `Calibration` holds what Zhang's method (OpenCV `stereoCalibrate`) yields for the two cameras - intrinsics,
distortion and the right camera's pose w.r.t. the left - and the rectification derived from it by
`cv2.stereoRectify`. After `rectify`, a scene point seen at left(x, y) is seen at right(x - d, y) with
disparity d >= 0, and `Q` reprojects (x, y, d) to millimetres in the rectified left camera frame
(the `cv2.reprojectImageTo3D` convention).

Stored as OpenCV FileStorage YAML (cellctl.vision.calibration_file reads and writes it).
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from cellctl.images import grey

# Keys a calibration file must have; everything else can be derived from them.
REQUIRED_KEYS: tuple[str, ...] = ("image_width", "image_height", "K1", "D1", "K2", "D2", "R", "T")
# Keys derived by cv2.stereoRectify; read back only as a complete set so they always belong together.
DERIVED_KEYS: tuple[str, ...] = ("R1", "R2", "P1", "P2", "Q")
# Plausibility: above this focal length (px) a camera matrix is a typing mistake, below this baseline (mm) so is T.
MAX_FOCAL_PX = 1e6
MIN_BASELINE_MM = 1.0
# Numbers of distortion coefficients OpenCV's camera model accepts.
_DISTORTION_SIZES = (4, 5, 8, 12, 14)


@dataclass(eq=False)
class Calibration:
    """Calibrated stereo pair: intrinsics, distortion, extrinsics (T in mm) and rectification."""

    image_size: tuple[int, int]  # (width, height) in px
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray  # rotation of the right camera w.r.t. the left (x_right = R @ x_left + T)
    T: np.ndarray  # translation of the same transform, mm
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    rms: float | None = None  # RMS reprojection error of the calibration, px
    # (left, right) identities of the calibrated cameras: /dev/v4l/by-id names or USB serials; None = unknown
    cameras: tuple[str, str] | None = None
    _maps: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, init=False, repr=False)
    _maps_lock: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False)

    def __post_init__(self) -> None:
        width, height = (int(v) for v in self.image_size)
        if width <= 0 or height <= 0:
            raise ValueError(f"image size must be positive, got {width}x{height} px")
        self.image_size = (width, height)
        self.K1 = _intrinsics(self.K1, "K1")
        self.K2 = _intrinsics(self.K2, "K2")
        self.D1 = _distortion(self.D1, "D1")
        self.D2 = _distortion(self.D2, "D2")
        self.R = _rotation(self.R, "R")
        self.T = _translation(self.T)
        self.R1 = _matrix(self.R1, (3, 3), "R1")
        self.R2 = _matrix(self.R2, (3, 3), "R2")
        self.P1 = _matrix(self.P1, (3, 4), "P1")
        self.P2 = _matrix(self.P2, (3, 4), "P2")
        self.Q = _matrix(self.Q, (4, 4), "Q")
        if abs(self.P2[1, 3]) > abs(self.P2[0, 3]):
            raise ValueError(
                "the cameras are one above the other (vertical baseline): mount them side by side, "
                "left and right, and calibrate again"
            )
        if self.P2[0, 3] >= 0:
            # OpenCV puts -f*baseline here when the right camera really is on the right; otherwise
            # disparities would come out negative and every depth downstream would be wrong.
            raise ValueError(
                "the right camera is not to the right of the left one (P2[0,3] >= 0): "
                "swap the LEFT and RIGHT cameras (or images) and calibrate again"
            )
        if self.rms is not None:
            self.rms = float(self.rms)

    @classmethod
    def from_extrinsics(
        cls,
        image_size: tuple[int, int],
        K1: np.ndarray,
        D1: np.ndarray,
        K2: np.ndarray,
        D2: np.ndarray,
        R: np.ndarray,
        T: np.ndarray,
        rms: float | None = None,
    ) -> Calibration:
        """Build a calibration from the stereo extrinsics, deriving the rectification."""
        size = (int(image_size[0]), int(image_size[1]))
        K1, K2 = _intrinsics(K1, "K1"), _intrinsics(K2, "K2")
        D1, D2 = _distortion(D1, "D1"), _distortion(D2, "D2")
        R, T = _rotation(R, "R"), _translation(T)
        # alpha=0 zooms so rectified images hold only valid pixels: no black wedges for the matcher.
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            K1, D1, K2, D2, size, R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0
        )
        return cls(size, K1, D1, K2, D2, R, T, R1, R2, P1, P2, Q, rms)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read a FileStorage YAML calibration (cellctl.vision.calibration_file)."""
        from cellctl.vision.calibration_file import read_calibration  # the file module builds on this one

        return read_calibration(path)

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the calibration as OpenCV FileStorage YAML (cellctl.vision.calibration_file)."""
        from cellctl.vision.calibration_file import write_calibration

        write_calibration(self, path)

    @property
    def baseline_mm(self) -> float:
        """Distance between the two optical centres, mm."""
        return float(np.linalg.norm(self.T))

    @property
    def focal_px(self) -> float:
        """Focal length of the rectified cameras, px."""
        return float(self.P1[0, 0])

    def check_image(self, img: np.ndarray) -> None:
        """Raise ValueError unless `img` has the calibrated size."""
        width, height = self.image_size
        shape = np.shape(img)
        if len(shape) < 2 or shape[0] != height or shape[1] != width:
            got = f"{shape[1]}x{shape[0]} px" if len(shape) >= 2 else f"an array of shape {shape}"
            raise ValueError(
                f"image is {got} but the calibration is for {width}x{height} px: "
                "capture at the calibrated resolution or calibrate again"
            )

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistort and rectify a left/right pair so epipolar lines are image rows."""
        self.check_image(left)
        self.check_image(right)
        left_map, right_map = self._rectify_map("left"), self._rectify_map("right")
        return (
            cv2.remap(left, left_map[0], left_map[1], cv2.INTER_LINEAR),
            cv2.remap(right, right_map[0], right_map[1], cv2.INTER_LINEAR),
        )

    def rectify_grey(self, image: np.ndarray, side: str, box: tuple[slice, slice] | None = None) -> np.ndarray:
        """One camera's raw image rectified as grey float32 (`side`: "left" or "right"), interpolated without
        rounding: the rectified pixels of `box` ((rows, columns) of the rectified image; all if None).

        `rectify` rounds the interpolated values to 8 bits again, and `grey` once more: ~0.35 DN of extra noise,
        about half the sensor's own on a black sole's faint texture, which the sub-pixel fits read. The
        same sampling positions as `rectify` (OpenCV's fixed-point maps; only the raw pixels the box reads are
        converted), the same values before the rounding."""
        self.check_image(image)
        map_xy, map_fraction = self._rectify_map(side)
        if box is not None:
            map_xy, map_fraction = map_xy[box], map_fraction[box]
        if map_xy.size == 0:
            return np.zeros(map_xy.shape[:2], np.float32)
        # The raw pixels the box samples: every map position and the next pixel on (bilinear), within the image.
        # (OpenCV's calls on the maps' box in place: numpy's on the strided view cost ~10 times as much.)
        height, width = np.shape(image)[:2]
        (x_low, x_high, _, _), (y_low, y_high, _, _) = (cv2.minMaxLoc(cv2.extractChannel(map_xy, k)) for k in (0, 1))
        x0, y0 = max(int(x_low), 0), max(int(y_low), 0)
        x1, y1 = min(int(x_high) + 2, width), min(int(y_high) + 2, height)
        if x1 <= x0 or y1 <= y0:  # the box samples nothing of the image: its border value, as `rectify` gives
            return np.zeros(map_xy.shape[:2], np.float32)
        raw = np.asarray(image)[y0:y1, x0:x1]
        # Positions in the crop (int16, far from saturating); a 4-vector is OpenCV's scalar, per channel.
        shifted = cv2.subtract(map_xy, np.array([x0, y0, 0.0, 0.0]))
        return cv2.remap(grey(raw.astype(np.float32)), shifted, map_fraction, cv2.INTER_LINEAR)

    def camera(self, side: str) -> CameraModel:
        """One camera of the pair ("left" or "right"): the one place that picks K, D, R, P by side."""
        if side == "left":
            return CameraModel(self.K1, self.D1, self.R1, self.P1)
        if side == "right":
            return CameraModel(self.K2, self.D2, self.R2, self.P2)
        raise ValueError(f"camera side must be 'left' or 'right', got {side!r}")

    def rectify_points_left(self, points: np.ndarray) -> np.ndarray:
        """Map left-image pixel positions (N x 2) to rectified left-image pixel positions."""
        return self.camera("left").rectify_points(points)

    def rectify_points_right(self, points: np.ndarray) -> np.ndarray:
        """Map right-image pixel positions (N x 2) to rectified right-image pixel positions."""
        return self.camera("right").rectify_points(points)

    def _rectify_map(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        # The maps cost ~100 ms to build and never change: build once per side, on first use.
        with self._maps_lock:
            if side not in self._maps:
                K, D, R, P = self.camera(side)
                self._maps[side] = cv2.initUndistortRectifyMap(K, D, R, P, self.image_size, cv2.CV_16SC2)
            return self._maps[side]


class CameraModel(NamedTuple):
    """One calibrated camera: intrinsics K, distortion D, and its rectification R (rotation) and P (projection)."""

    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray

    def rectify_points(self, points: np.ndarray) -> np.ndarray:
        """Map raw pixel positions (N x 2) of this camera to rectified pixel positions."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 1, 2)
        # More iterations than the default 5: the default leaves ~0.1 px error near the corners of the image.
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
        return cv2.undistortPoints(pts, self.K, self.D, R=self.R, P=self.P, criteria=criteria).reshape(-1, 2)


def _matrix(value: np.ndarray, shape: tuple[int, int], name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.size != shape[0] * shape[1]:
        raise ValueError(f"{name} must be {shape[0]}x{shape[1]}, got shape {arr.shape}")
    arr = arr.reshape(shape).copy()
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _intrinsics(value: np.ndarray, name: str) -> np.ndarray:
    """A camera matrix with positive, finite focal lengths below 1e6 px (0 or 1e30 are typing mistakes)."""
    arr = _matrix(value, (3, 3), name)
    fx, fy = arr[0, 0], arr[1, 1]
    if not (0 < fx < MAX_FOCAL_PX and 0 < fy < MAX_FOCAL_PX) or arr[2, 2] != 1.0:
        raise ValueError(
            f"{name} is not a camera matrix: focal lengths {fx:g}, {fy:g} px must be in 0..{MAX_FOCAL_PX:g} and "
            f"{name}[2][2] must be 1 (got {arr[2, 2]:g}): re-calibrate or correct the file"
        )
    return arr


def _translation(value: np.ndarray) -> np.ndarray:
    arr = _matrix(value, (3, 1), "T")
    if np.linalg.norm(arr) < MIN_BASELINE_MM:
        raise ValueError(
            f"T = {arr.ravel().tolist()} mm puts both cameras at the same place (baseline "
            f"{np.linalg.norm(arr):g} mm): re-calibrate or correct the file"
        )
    return arr


def _distortion(value: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(1, -1)
    if arr.shape[1] not in _DISTORTION_SIZES:
        raise ValueError(f"{name} must have 4, 5, 8, 12 or 14 distortion coefficients, got {arr.shape[1]}")
    return _matrix(arr, arr.shape, name)


def _rotation(value: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.size == 3:  # a Rodrigues vector, as some tools store it
        arr = np.asarray(cv2.Rodrigues(arr.reshape(3, 1))[0], dtype=np.float64)
    arr = _matrix(arr, (3, 3), name)
    if not np.allclose(arr @ arr.T, np.eye(3), atol=1e-6) or np.linalg.det(arr) <= 0:
        raise ValueError(f"{name} is not a rotation matrix")
    return arr
