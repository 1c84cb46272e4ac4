"""Stereo calibration from checkerboard pairs (Zhang's method through OpenCV), with outlier pair rejection.

As in section 2.1 of Wang et al. 2022: detect the board's inner corners in every pair, calibrate, drop the
pairs whose reprojection error stands out (a board that moved between the two exposures, a blurred or
mis-detected view) and calibrate again on the rest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.calib.board import Checkerboard, find_corners
from cellctl.calib.pairs import PairFiles
from cellctl.calib.report import CalibrationResult, PairResult
from cellctl.images import read_image
from cellctl.vision.calibration import Calibration

MIN_PAIRS = 6  # below this the distortion and extrinsics are poorly constrained
MAD_K = 3.0  # outlier threshold: median + MAD_K robust standard deviations
MIN_THRESHOLD_RATIO = 2.0  # ...but never below this multiple of the median (see _threshold)
_CALIB_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-9)


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


def detect_views(pairs: Sequence[PairFiles], board: Checkerboard) -> list[BoardView]:
    """Read each pair and find the board in both images; unusable pairs carry a `problem`."""
    views = [_detect_view(pair, board) for pair in pairs]
    _check_sizes(views)
    return views


def _detect_view(pair: PairFiles, board: Checkerboard) -> BoardView:
    images: dict[str, np.ndarray] = {}
    names: dict[str, str] = {}
    for side, path in (("left", pair.left), ("right", pair.right)):
        if path is None:
            return BoardView(pair.name, None, None, problem=f"{side}_{pair.name} image missing")
        try:
            image = read_image(path, cv2.IMREAD_GRAYSCALE)
        except (OSError, ValueError) as exc:
            return BoardView(pair.name, None, None, problem=f"cannot read {path.name}: {exc}")
        images[side], names[side] = image, path.name
    left, right = images["left"], images["right"]
    size = (left.shape[1], left.shape[0])
    if left.shape != right.shape:
        raise ValueError(
            f"{names['left']} is {left.shape[1]}x{left.shape[0]} px but {names['right']} is "
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
    size = _image_size(views[0])
    objects = [board.object_points()] * len(views)
    lefts = [_corners(view.left, view).reshape(-1, 1, 2) for view in views]
    rights = [_corners(view.right, view).reshape(-1, 1, 2) for view in views]
    # k3 mostly fits noise for the mild distortion of machine-vision lenses, and makes k1/k2 unstable.
    flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
    _, K1, D1, _, _ = cv2.calibrateCamera(objects, lefts, size, None, None, flags=flags, criteria=_CALIB_CRITERIA)
    _, K2, D2, _, _ = cv2.calibrateCamera(objects, rights, size, None, None, flags=flags, criteria=_CALIB_CRITERIA)
    # R and T are outputs: None lets OpenCV allocate them (its stubs type them as required inputs).
    rms, K1, D1, K2, D2, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(  # type: ignore[call-overload]
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


def _image_size(view: BoardView) -> tuple[int, int]:
    if view.image_size is None:
        raise ValueError(f"pair {view.name} has no image size: it was not read")
    return view.image_size


def _corners(corners: np.ndarray | None, view: BoardView) -> np.ndarray:
    if corners is None:
        raise ValueError(f"pair {view.name} has no corners: {view.problem}")
    return corners


def _threshold(errors: np.ndarray) -> float:
    """Robust outlier threshold: median + MAD_K * 1.4826 * MAD, and at least MIN_THRESHOLD_RATIO * median.

    The floor matters when all pairs are good: their errors then agree so closely that the MAD alone
    would flag pairs only a few hundredths of a pixel worse than the rest.
    """
    median = float(np.median(errors))
    mad = float(np.median(np.abs(errors - median)))
    return max(median + MAD_K * 1.4826 * mad, MIN_THRESHOLD_RATIO * median)
