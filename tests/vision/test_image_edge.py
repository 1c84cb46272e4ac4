"""The outline moved onto the edge both cameras' silhouettes show (cellctl.vision.image_edge)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from cellctl.vision.image_edge import edge_shift, silhouette_offsets

RADIUS = 50.0
HEIGHT = 20.0
FOCAL = 1400.0
SIZE = 900


def camera_image(camera: np.ndarray, wall: bool = True) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """A cylinder's silhouette seen by a pinhole camera looking straight down from `camera` (without `wall`:
    only its top face changed, the wall lit like the table), and the camera's projection."""
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    direction = np.column_stack([(u.ravel() - SIZE / 2) / FOCAL, (v.ravel() - SIZE / 2) / FOCAL])
    hit = np.zeros(u.size, bool)
    for z in np.linspace(0.0, HEIGHT, 81) if wall else [HEIGHT]:
        hit |= np.linalg.norm(camera[:2] + direction * (camera[2] - z), axis=1) <= RADIUS

    def project(points: np.ndarray) -> np.ndarray:
        rel = points - camera
        return np.column_stack([FOCAL * rel[:, 0] / -rel[:, 2], FOCAL * rel[:, 1] / -rel[:, 2]]) + SIZE / 2

    return hit.reshape(SIZE, SIZE), project


def circle(radius: float) -> tuple[np.ndarray, np.ndarray]:
    angle = np.linspace(0.0, 2 * np.pi, int(2 * np.pi * RADIUS), endpoint=False)
    outward = np.column_stack([np.cos(angle), np.sin(angle)])
    return radius * outward, outward


@pytest.mark.parametrize("wall", [True, False])
def test_each_camera_places_the_edge_at_the_height_of_its_silhouette(wall: bool) -> None:
    """A camera off to +x, an outline 1.5 mm inside the circle: the -x side's top edge (the wall faces away) is
    placed on the circle; the +x wall's foot too where the wall shows a change. Where it does not (lit like the
    table), the foot reading ends inside the sole and is the nearer one: never a claim beyond the edge."""
    camera = np.array([120.0, 0.0, 550.0])
    changed, project = camera_image(camera, wall)
    ring, outward = circle(RADIUS - 1.5)
    found = silhouette_offsets(ring, outward, np.full(len(ring), HEIGHT), changed, project, camera)
    away = np.sum(outward * (camera[:2] - ring), axis=1) <= 0  # the wall faces away from the camera
    assert np.mean(np.isfinite(found[away])) > 0.9
    assert np.nanmax(np.abs(found[away] - 1.5)) <= 0.5
    if wall:
        assert np.nanmax(np.abs(found[~away] - 1.5)) <= 0.5
    else:
        assert np.nanmax(found[~away]) <= 2.0 and np.nanmedian(found[~away]) < 1.0
    # The top edge taken at the table's height instead lies several mm beyond the edge.
    flat = silhouette_offsets(ring, outward, np.zeros(len(ring)), changed, project, camera)
    assert np.nanmax(flat - 1.5) > 2.0


def test_the_outline_moves_only_where_both_cameras_agree() -> None:
    n = 200
    left, right = np.zeros(n), np.zeros(n)
    left[20:40] = right[20:40] = 1.2  # both see the edge 1.2 mm beyond: a dent of the outline
    left[100:120] = 1.5  # one camera fooled (a shadow past the edge): no move
    right[150:170] = np.nan  # the other has no edge there: no move
    left[150:170] = 1.5
    left[60:80] = right[60:80] = 0.3  # within the edge's scatter: no move
    left[180:195] = right[180:195] = -1.2  # both masks end inside the outline: no evidence, no move
    shift = edge_shift(left, right)
    assert np.all(np.abs(shift[25:35] - 1.2) < 0.05)
    assert np.all(shift[100:120] == 0.0) and np.all(shift[150:170] == 0.0) and np.all(shift[60:80] == 0.0)
    assert np.all(shift[180:195] == 0.0)
