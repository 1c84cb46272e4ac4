"""The right-image outline check where the right camera's ray from the table just outside a tall wall grazes its
top edge: there the table lands within a pixel of the sole in the image, inside the change mask's blurred
boundary, so the check reads the table further out past the edge instead (checks.RIGHT_CLEAR_MM)."""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np
import pytest

from cellctl.errors import FailureKind
from cellctl.vision import checks
from cellctl.vision.checks import check_outline_right
from cellctl.vision.footprint import Footprint

HALF = np.array([100.0, 40.0])  # a box sole |x| <= 100, |y| <= 40 mm...
HEIGHT = 22.0  # ...this tall, with vertical walls
# The camera 27 mm to -y of the box's middle: its ray from the table 3 mm beyond the +y wall passes the wall's
# top edge 0.2 mm out (22 / 550 of the 70 mm to the camera is 2.8 mm), half a pixel in the image.
CAMERA = np.array([0.0, -27.0, 550.0])
FOCAL, SIZE = 1400.0, 1400
NOTHING_AT_TABLE_LEVEL = Footprint(np.zeros((1, 1), np.uint8), (-200.0, -200.0), 0.5)


def box_outline(shrink_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The box's outline 1 mm apart (counter-clockwise) `shrink_mm` inside the true edge, with outward normals."""
    hx, hy = HALF - shrink_mm
    sides = [
        ((-hx, -hy), (hx, -hy), (0.0, -1.0)),
        ((hx, -hy), (hx, hy), (1.0, 0.0)),
        ((hx, hy), (-hx, hy), (0.0, 1.0)),
        ((-hx, hy), (-hx, -hy), (-1.0, 0.0)),
    ]
    points, normals = [], []
    for start, end, normal in sides:
        count = int(round(np.linalg.norm(np.subtract(end, start))))
        t = np.arange(count)[:, None] / count
        points.append(np.array(start) + t * np.subtract(end, start))
        normals.append(np.repeat([normal], count, axis=0))
    return np.concatenate(points), np.concatenate(normals)


def height(xy: np.ndarray) -> np.ndarray:
    return np.where(np.all(np.abs(xy) <= HALF, axis=1), HEIGHT, np.nan)


def project(points: np.ndarray) -> np.ndarray:
    rel = points - CAMERA
    return np.column_stack([FOCAL * rel[:, 0] / -rel[:, 2], FOCAL * rel[:, 1] / -rel[:, 2]]) + SIZE / 2


@cache
def changed_blurred() -> np.ndarray:
    """Pixels whose ray meets the box, the boundary one pixel wider (a change mask's blurred edge)."""
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    direction = np.column_stack([(u.ravel() - SIZE / 2) / FOCAL, (v.ravel() - SIZE / 2) / FOCAL])
    hit = np.zeros(u.size, bool)
    for z in np.linspace(0.0, HEIGHT, 12):  # vertical walls: a ray that meets the box is inside it at some height
        hit |= height(CAMERA[:2] + direction * (CAMERA[2] - z)) >= z - 1e-9
    return cv2.dilate(hit.reshape(SIZE, SIZE).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0


def right_check(shrink_mm: float = 0.0) -> checks.CheckFailure | None:
    outline, outward = box_outline(shrink_mm)
    edge = np.full(len(outline), HEIGHT)
    return check_outline_right(
        outline, outward, edge, changed_blurred(), project, CAMERA, height, NOTHING_AT_TABLE_LEVEL
    )


def test_a_ray_grazing_the_top_edge_is_not_read_as_the_table(monkeypatch: pytest.MonkeyPatch) -> None:
    assert right_check() is None
    # Read where the ray grazes the edge, the blurred boundary refuses the true outline along the +y wall.
    monkeypatch.setattr(checks, "RIGHT_CLEAR_MM", 0.0)
    problem = right_check()
    assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT


def test_an_outline_inside_the_edge_is_still_refused() -> None:
    for shrink in (1.5, 2.0):
        problem = right_check(shrink)
        assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT
