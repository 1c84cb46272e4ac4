"""Stereo calibration from checkerboard pairs (Zhang's method through OpenCV), with outlier pair rejection.

As in section 2.1 of Wang et al. 2022: detect the board's inner corners in every pair, calibrate, drop the
pairs whose reprojection error stands out (a board that moved between the two exposures, a blurred or
mis-detected view) and calibrate again on the rest.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cellctl.images import read_image
from cellctl.vision.calibration import Calibration

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
MIN_PAIRS = 6  # below this the distortion and extrinsics are poorly constrained
MAD_K = 3.0  # outlier threshold: median + MAD_K robust standard deviations
MIN_THRESHOLD_RATIO = 2.0  # ...but never below this multiple of the median (see _threshold)
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
_CALIB_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-9)


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


@dataclass(frozen=True)
class PairFiles:
    """The two image files of one capture."""

    name: str  # the NN of left_NN.png / right_NN.png
    left: Path | None
    right: Path | None


@dataclass
class BoardView:
    """Board corners found in one pair, or why they were not."""

    name: str
    left: np.ndarray | None  # N x 2 corner positions, px, in the board's canonical order
    right: np.ndarray | None
    image_size: tuple[int, int] | None = None  # (width, height) of both images
    problem: str | None = None  # set when the pair cannot be used

    @property
    def usable(self) -> bool:
        return self.problem is None


@dataclass
class PairResult:
    """The outcome for one pair: kept, rejected as an outlier, or skipped before calibrating."""

    name: str
    status: str  # "kept", "rejected" or "skipped"
    error_px: float | None  # RMS reprojection error over both images (for rejected pairs: when rejected)
    note: str = ""


@dataclass
class CalibrationResult:
    """A calibration and the account of how each pair contributed to it."""

    calibration: Calibration
    pairs: list[PairResult]
    threshold_px: float  # outlier threshold of the last rejection round

    @property
    def kept(self) -> list[str]:
        return [p.name for p in self.pairs if p.status == "kept"]

    @property
    def rejected(self) -> list[str]:
        """Names of the pairs not used: outliers and pairs without usable corners."""
        return [p.name for p in self.pairs if p.status != "kept"]

    def table(self) -> str:
        """The per-pair table printed by `cellctl calibrate`."""
        lines = [f"{'pair':<8}{'status':<10}{'error px':>9}  note"]
        for pair in self.pairs:
            error = f"{pair.error_px:9.3f}" if pair.error_px is not None else f"{'-':>9}"
            lines.append(f"{pair.name:<8}{pair.status:<10}{error}  {pair.note}".rstrip())
        c = self.calibration
        lines.append(
            f"kept {len(self.kept)} of {len(self.pairs)} pairs; final outlier threshold {self.threshold_px:.3f} px; "
            f"RMS {c.rms:.3f} px; baseline {c.baseline_mm:.2f} mm; "
            f"f {c.K1[0, 0]:.1f}/{c.K2[0, 0]:.1f} px (left/right)"
        )
        return "\n".join(lines)

    def error_chart(self) -> np.ndarray:
        """Bar chart of the per-pair errors with the outlier threshold, as a BGR image."""
        return _draw_error_chart(self.pairs, self.threshold_px)


def find_pairs(directory: str | os.PathLike[str]) -> list[PairFiles]:
    """The left_NN / right_NN image pairs in `directory`, in natural order of NN."""
    folder = Path(directory)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a directory of left_NN.png / right_NN.png pairs")
    found: dict[str, dict[str, Path]] = {}
    for path in folder.iterdir():
        match = re.fullmatch(r"(left|right)_(.+)", path.stem)
        if match and path.suffix.lower() in IMAGE_EXTENSIONS:
            if not path.is_file():  # a FIFO would block the image reader forever
                raise ValueError(f"{path} is not a regular image file (a FIFO, device or directory?): move it away")
            found.setdefault(match.group(2), {})[match.group(1)] = path
    if not found:
        raise ValueError(f"no left_NN.png / right_NN.png images in {folder}: capture checkerboard pairs there first")

    def natural(name: str) -> list[object]:
        return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]

    names = sorted(found, key=natural)
    return [PairFiles(name, found[name].get("left"), found[name].get("right")) for name in names]


def find_corners(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """Sub-pixel inner corners of `board` in `image` (N x 2, canonical order), or None if not all found."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
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


def detect_views(pairs: Sequence[PairFiles], board: Checkerboard) -> list[BoardView]:
    """Read each pair and find the board in both images; unusable pairs carry a `problem`."""
    views = [_detect_view(pair, board) for pair in pairs]
    _check_sizes(views)
    return views


def _detect_view(pair: PairFiles, board: Checkerboard) -> BoardView:
    images: dict[str, np.ndarray] = {}
    for side, path in (("left", pair.left), ("right", pair.right)):
        if path is None:
            return BoardView(pair.name, None, None, problem=f"{side}_{pair.name} image missing")
        try:
            image = read_image(path, cv2.IMREAD_GRAYSCALE)
        except (OSError, ValueError) as exc:
            return BoardView(pair.name, None, None, problem=f"cannot read {path.name}: {exc}")
        images[side] = image
    left, right = images["left"], images["right"]
    size = (left.shape[1], left.shape[0])
    if left.shape != right.shape:
        raise ValueError(
            f"{pair.left.name} is {left.shape[1]}x{left.shape[0]} px but {pair.right.name} is "
            f"{right.shape[1]}x{right.shape[0]} px: both cameras must capture at the same resolution"
        )
    corners = {side: find_corners(image, board) for side, image in images.items()}
    missing = [f"{side}_{pair.name}" for side in ("left", "right") if corners[side] is None]
    problem = f"no {board.cols}x{board.rows} corners found in {' and '.join(missing)}" if missing else None
    return BoardView(pair.name, corners["left"], corners["right"], size, problem)


def _check_sizes(views: Sequence[BoardView]) -> None:
    sizes = {view.image_size for view in views if view.image_size is not None}
    if len(sizes) > 1:
        listing = ", ".join(f"{v.name}: {v.image_size[0]}x{v.image_size[1]}" for v in views if v.image_size)
        raise ValueError(f"the pairs have different image sizes ({listing}): capture all pairs at one resolution")


def calibrate_views(
    views: Sequence[BoardView],
    board: Checkerboard,
    *,
    min_pairs: int = MIN_PAIRS,
    fit_k3: bool = False,
) -> CalibrationResult:
    """Calibrate the stereo pair from detected views, rejecting outlier pairs and recalibrating."""
    if min_pairs < 3:
        raise ValueError(f"min_pairs must be at least 3 (OpenCV's minimum), got {min_pairs}")
    usable = [view for view in views if view.usable]
    if len(usable) < min_pairs:
        skipped = "; ".join(view.problem for view in views if view.problem)
        raise ValueError(
            f"too few usable pairs: {len(usable)} of {len(views)}, at least {min_pairs} needed"
            + (f" ({skipped})" if skipped else "")
            + ": capture more pairs with the whole board visible in both cameras"
        )
    results = {view.name: PairResult(view.name, "skipped", None, view.problem or "") for view in views}
    kept = list(usable)
    while True:
        calibration, errors = _calibrate(kept, board, fit_k3)
        threshold = _threshold(errors)
        worst = int(np.argmax(errors))
        # Drop only the worst pair per round: a bad pair skews the whole calibration, which inflates the
        # errors of good pairs too, so they are judged again once it is gone. Never go below min_pairs.
        if errors[worst] <= threshold or len(kept) <= min_pairs:
            break
        results[kept[worst].name] = PairResult(
            kept[worst].name, "rejected", float(errors[worst]), f"error above the {threshold:.3f} px threshold"
        )
        kept = kept[:worst] + kept[worst + 1 :]
    for view, error in zip(kept, errors):
        results[view.name] = PairResult(view.name, "kept", float(error))
    return CalibrationResult(calibration, [results[view.name] for view in views], threshold)


def _calibrate(views: Sequence[BoardView], board: Checkerboard, fit_k3: bool) -> tuple[Calibration, np.ndarray]:
    """One calibration round: each camera alone for a start, then both jointly. Returns per-pair errors."""
    size = views[0].image_size
    objects = [board.object_points()] * len(views)
    lefts = [view.left.reshape(-1, 1, 2) for view in views]
    rights = [view.right.reshape(-1, 1, 2) for view in views]
    # k3 mostly fits noise for the mild distortion of machine-vision lenses, and makes k1/k2 unstable.
    flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
    _, K1, D1, _, _ = cv2.calibrateCamera(objects, lefts, size, None, None, flags=flags, criteria=_CALIB_CRITERIA)
    _, K2, D2, _, _ = cv2.calibrateCamera(objects, rights, size, None, None, flags=flags, criteria=_CALIB_CRITERIA)
    rms, K1, D1, K2, D2, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
        objects, lefts, rights, K1, D1, K2, D2, size, None, None,
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=_CALIB_CRITERIA,
    )  # fmt: skip
    # Both images have the same number of corners, so the pair's RMS is the quadratic mean of the two.
    errors = np.sqrt(np.mean(np.square(np.asarray(per_view).reshape(-1, 2)), axis=1))
    try:
        calibration = Calibration.from_extrinsics(size, K1, D1, K2, D2, R, T, rms=rms)
    except ValueError as exc:
        raise ValueError(f"{exc} (the calibration found the right camera on the left)") from None
    return calibration, errors


def _threshold(errors: np.ndarray) -> float:
    """Robust outlier threshold: median + MAD_K * 1.4826 * MAD, and at least MIN_THRESHOLD_RATIO * median.

    The floor matters when all pairs are good: their errors then agree so closely that the MAD alone
    would flag pairs only a few hundredths of a pixel worse than the rest.
    """
    median = float(np.median(errors))
    mad = float(np.median(np.abs(errors - median)))
    return max(median + MAD_K * 1.4826 * mad, MIN_THRESHOLD_RATIO * median)


def _draw_error_chart(pairs: Sequence[PairResult], threshold_px: float) -> np.ndarray:
    colours = {"kept": (80, 170, 60), "rejected": (50, 50, 220), "skipped": (150, 150, 150)}
    bar, gap, left, bottom, top, plot_h = 36, 12, 70, 60, 40, 320
    width = max(480, left + len(pairs) * (bar + gap) + gap + 20)
    chart = np.full((top + plot_h + bottom, width, 3), 255, np.uint8)
    measured = [p.error_px for p in pairs if p.error_px is not None]
    finite_threshold = threshold_px if np.isfinite(threshold_px) else 0.0
    scale_max = max([*measured, finite_threshold, 1e-3])
    if finite_threshold > 0:
        # One wild pair would flatten all the others: clip the axis and label the clipped bars instead.
        scale_max = min(scale_max, 4.0 * finite_threshold)
    scale_max *= 1.1
    base_y = top + plot_h

    def y_of(value: float) -> int:
        return int(round(base_y - value / scale_max * plot_h))

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(chart, "RMS reprojection error per pair (px)", (left, 25), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    for tick in np.linspace(0, scale_max, 5):
        y = y_of(tick)
        cv2.line(chart, (left - 5, y), (width - 10, y), (225, 225, 225), 1)
        cv2.putText(chart, f"{tick:.2f}", (8, y + 5), font, 0.45, (60, 60, 60), 1, cv2.LINE_AA)
    for i, pair in enumerate(pairs):
        x0 = left + gap + i * (bar + gap)
        if pair.error_px is not None:
            clipped = pair.error_px > scale_max
            bar_top = y_of(min(pair.error_px, scale_max))
            cv2.rectangle(chart, (x0, bar_top), (x0 + bar, base_y), colours[pair.status], -1)
            if clipped:
                cv2.putText(chart, f"{pair.error_px:.2f}", (x0, top - 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        else:  # skipped: no error to show, mark the slot
            cv2.putText(chart, "x", (x0 + bar // 2 - 6, base_y - 6), font, 0.6, colours["skipped"], 2, cv2.LINE_AA)
        cv2.putText(chart, pair.name[:5], (x0, base_y + 20), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.line(chart, (left, base_y), (width - 10, base_y), (0, 0, 0), 1)
    if finite_threshold > 0:
        y = y_of(finite_threshold)
        for x in range(left, width - 10, 14):  # dashed: OpenCV has no dashed line
            cv2.line(chart, (x, y), (min(x + 8, width - 10), y), (0, 0, 200), 1)
        label = f"threshold {finite_threshold:.3f}"
        cv2.putText(chart, label, (width - 190, y - 6), font, 0.45, (0, 0, 200), 1, cv2.LINE_AA)
    legend = "green: kept   red: rejected   x: no corners (skipped)"
    cv2.putText(chart, legend, (left, base_y + 45), font, 0.45, (60, 60, 60), 1, cv2.LINE_AA)
    return chart
