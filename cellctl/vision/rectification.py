"""Checking a rectification: matched features must lie on the same row in both rectified images.

The residual vertical disparity of real scene features is the figure that tells whether a calibration
still holds (a camera knocked after calibrating shows up here first), and the side-by-side view with
equally spaced rows is the picture of it (Figure 4 of Wang et al. 2022).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.images import bgr, grey

MIN_MATCHES = 20  # fewer inliers than this say more about the scene than about the rectification
MAX_MISMATCH_FRACTION = 0.25  # beyond this the scene is too repetitive for the figures to be trusted


@dataclass(frozen=True)
class VerticalDisparity:
    """Row offsets (left y - right y) of matched features in a rectified pair, px."""

    dy: np.ndarray  # one value per matched feature kept as a correct match
    matches: int  # candidate matches before the checks

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.dy))))

    @property
    def median(self) -> float:
        return float(np.median(self.dy))

    @property
    def p95(self) -> float:
        """95th percentile of |dy|."""
        return float(np.percentile(np.abs(self.dy), 95))

    @property
    def mismatch_fraction(self) -> float:
        """Share of the candidate matches set aside as wrong."""
        return 1.0 - self.dy.size / self.matches

    def summary(self) -> str:
        text = (
            f"residual vertical disparity over {self.dy.size} matched features: RMS {self.rms:.3f} px, "
            f"median {self.median:+.3f} px, 95% within {self.p95:.3f} px "
            f"({self.matches - self.dy.size} of {self.matches} matches set aside as mismatches)"
        )
        if self.mismatch_fraction > MAX_MISMATCH_FRACTION:
            text += (
                "\nwarning: many mismatches, so these figures are unreliable: use images of a scene with "
                "irregular texture (not a checkerboard or other repeated pattern)"
            )
        return text


def vertical_disparity(left: np.ndarray, right: np.ndarray) -> VerticalDisparity:
    """Measure the row offsets of SIFT matches between a rectified left and right image.

    SIFT rather than ORB: its keypoints are refined to sub-pixel positions, ORB's are not, and a check
    aiming at tenths of a pixel needs the former. Wrong matches are removed by the ratio test, a RANSAC
    fit of the fundamental matrix, and finally by their row offset, relative to the median offset of all
    matches and its robust spread. None of these assumes the rectification is right, so a bad one still
    shows in the figures instead of being filtered away. The last step is needed for flat, repetitive
    scenes such as a checkerboard: a plane leaves the fundamental matrix undetermined, and RANSAC then
    accepts matches one square off.
    """
    sift = cv2.SIFT_create(nfeatures=4000)  # type: ignore[attr-defined]  # in OpenCV's main module since 4.4, not in its stubs
    kp_left, desc_left = sift.detectAndCompute(grey(left), None)
    kp_right, desc_right = sift.detectAndCompute(grey(right), None)
    if desc_left is None or desc_right is None or len(kp_left) < MIN_MATCHES or len(kp_right) < MIN_MATCHES:
        raise ValueError(_too_few(min(len(kp_left), len(kp_right)), "features"))
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_left, desc_right, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < 0.75 * m[1].distance]
    if len(good) < MIN_MATCHES:
        raise ValueError(_too_few(len(good), "matches"))
    pts_left = np.array([kp_left[m.queryIdx].pt for m in good], dtype=np.float64)
    pts_right = np.array([kp_right[m.trainIdx].pt for m in good], dtype=np.float64)
    _, inliers = cv2.findFundamentalMat(pts_left, pts_right, cv2.FM_RANSAC, 1.0, 0.999)
    if inliers is None or int(inliers.sum()) < MIN_MATCHES:
        raise ValueError(_too_few(0 if inliers is None else int(inliers.sum()), "consistent matches"))
    keep = inliers.ravel().astype(bool)
    dy = pts_left[keep, 1] - pts_right[keep, 1]
    median = np.median(dy)
    spread = 1.4826 * np.median(np.abs(dy - median))
    # 5 robust sigmas keep all of a real residual (even a tilted one); the 1 px floor keeps sub-pixel
    # noise from being trimmed when almost all matches agree.
    dy = dy[np.abs(dy - median) <= max(5.0 * spread, 1.0)]
    if dy.size < MIN_MATCHES:
        raise ValueError(_too_few(dy.size, "consistent matches"))
    return VerticalDisparity(dy, len(good))


def side_by_side(left: np.ndarray, right: np.ndarray, lines: int = 16) -> np.ndarray:
    """Left and right next to each other with `lines` equally spaced horizontal lines (BGR)."""
    pair = np.hstack([bgr(left), bgr(right)])
    spacing = pair.shape[0] / (lines + 1)
    for i in range(1, lines + 1):
        y = int(round(i * spacing))
        cv2.line(pair, (0, y), (pair.shape[1] - 1, y), (0, 255, 0), 1, cv2.LINE_AA)
    return pair


def _too_few(count: int, what: str) -> str:
    return (
        f"only {count} {what} between the two images (at least {MIN_MATCHES} needed): "
        "check the images show the same textured scene, well lit and in focus"
    )
