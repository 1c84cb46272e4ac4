"""Teach targets measured by the cameras: ArUco markers located in 3-D in the cell's table frame.

    targets = locate_markers(calib, left, right, table)      # table: TablePlane of the same pair
    for t in targets: print(t.marker_id, t.table_xyz)

The robot touches the centre of each marker (printed on a teach fixture, or carried by the robot on a
plate whose centre is its tool point); the cell finds the same centre in both rectified images and
triangulates it. The centre is the intersection of the marker's diagonals, which perspective preserves
(the mean of the four corners does not), refined to sub-pixel by OpenCV. Markers of OpenCV's 4x4 dictionary
(ids 0..49) are used: large cells, found reliably at the rig's ~0.4 mm per pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.vision.calibration import Calibration
from cellctl.vision.table import TablePlane

DICTIONARY = cv2.aruco.DICT_4X4_50
#: Rectified rows of one marker's centre in the two images may differ this much (px) before the pair is refused.
MAX_ROW_MISMATCH_PX = 1.0


@dataclass(frozen=True)
class TeachTarget:
    """One marker seen by both cameras."""

    marker_id: int
    table_xyz: np.ndarray  # 3, mm in the table frame
    left_px: np.ndarray  # 2, centre in the rectified left image
    disparity_px: float


def locate_markers(calib: Calibration, left: np.ndarray, right: np.ndarray, table: TablePlane) -> list[TeachTarget]:
    """Markers seen in both raw images, located in the table frame; sorted by id."""
    rect_left, rect_right = calib.rectify(left, right)
    grey_left, grey_right = _grey(rect_left), _grey(rect_right)
    seen_left, seen_right = _centres(grey_left), _centres(grey_right)
    camera_to_table = table.camera_to_table()
    targets = []
    for marker_id in sorted(set(seen_left) & set(seen_right)):
        (xl, yl, side), (xr, yr, _) = seen_left[marker_id], seen_right[marker_id]
        if abs(yl - yr) > MAX_ROW_MISMATCH_PX:  # not the same point: a reflection, or a calibration that is off
            continue
        disparity = _refined_disparity(grey_left, grey_right, (xl, yl), xl - xr, side)
        if disparity is None:
            continue
        homogeneous = calib.Q @ np.array([xl, yl, disparity, 1.0])
        camera = homogeneous[:3] / homogeneous[3]
        table_xyz = camera_to_table[:3, :3] @ camera + camera_to_table[:3, 3]
        targets.append(TeachTarget(marker_id, table_xyz, np.array([xl, yl]), float(disparity)))
    return targets


def marker_image(marker_id: int, pixels: int) -> np.ndarray:
    """A printable marker (uint8, white border of one cell) for the teach fixture and the tests."""
    dictionary = cv2.aruco.getPredefinedDictionary(DICTIONARY)
    inner = cv2.aruco.generateImageMarker(dictionary, marker_id, pixels * 6 // 8)
    border = (pixels - inner.shape[0]) // 2
    return cv2.copyMakeBorder(inner, border, pixels - inner.shape[0] - border, border, pixels - inner.shape[0] - border, cv2.BORDER_CONSTANT, value=255)  # fmt: skip


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def _centres(grey: np.ndarray) -> dict[int, tuple[float, float, float]]:
    """Centre (x, y) and side length (px) of every marker found once (an id seen twice is ambiguous)."""
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY), parameters)
    corners, ids, _ = detector.detectMarkers(grey)
    if ids is None:
        return {}
    found: dict[int, list[tuple[float, float, float]]] = {}
    for quad, marker_id in zip(corners, ids.ravel()):
        points = quad.reshape(4, 2).astype(float)
        side = float(np.mean(np.linalg.norm(points - np.roll(points, 1, axis=0), axis=1)))
        found.setdefault(int(marker_id), []).append((*_diagonal_intersection(points), side))
    return {marker_id: centres[0] for marker_id, centres in found.items() if len(centres) == 1}


def _refined_disparity(
    left: np.ndarray, right: np.ndarray, centre: tuple[float, float], coarse: float, side: float
) -> float | None:
    """Disparity of the marker patch by normalised cross-correlation along the row, to sub-pixel.

    The corners alone carry ~0.3 px of disparity noise (0.7 mm of height at the rig's distance); the whole
    patch matched at once averages it out. For a tilted marker the disparity varies linearly across the
    patch, so the patch's disparity is that of its centre.
    """
    half = int(side * 0.6)
    search = 3
    x, y = int(round(centre[0])), int(round(centre[1]))
    xr = int(round(centre[0] - coarse))
    height, width = left.shape[:2]
    if (
        min(x - half, xr - half - search, y - half) < 0
        or max(x + half, xr + half + search) >= width
        or y + half >= height
    ):
        return None
    template = left[y - half : y + half + 1, x - half : x + half + 1].astype(np.float32)
    strip = right[y - half : y + half + 1, xr - half - search : xr + half + search + 1].astype(np.float32)
    scores = cv2.matchTemplate(strip, template, cv2.TM_CCOEFF_NORMED).ravel()
    best = int(np.argmax(scores))
    if scores[best] < 0.8 or best in (0, len(scores) - 1):  # no clear match inside the search window
        return None
    a, b, c = scores[best - 1], scores[best], scores[best + 1]
    offset = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) < 0 else 0.0
    matched_x = xr - search + best + offset  # right-image x of the template's centre column x
    return float(x - matched_x)  # at column x; within half a pixel of the marker centre, the same


def _diagonal_intersection(quad: np.ndarray) -> tuple[float, float]:
    """Where corner 0-2 and corner 1-3 cross."""
    p, r = quad[0], quad[2] - quad[0]
    q, s = quad[1], quad[3] - quad[1]
    cross = r[0] * s[1] - r[1] * s[0]
    if abs(cross) < 1e-9:
        centre = quad.mean(axis=0)
    else:
        t = ((q[0] - p[0]) * s[1] - (q[1] - p[1]) * s[0]) / cross
        centre = p + t * r
    return float(centre[0]), float(centre[1])
