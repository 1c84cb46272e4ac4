"""A cast shadow's slivers beside the sole in a change mask (cellctl.vision.shadow), on a synthetic round sole
seen straight from above at the rig's pixel size: a textured table, its taught picture, and the current one
with the sole, a two-level shadow on one side, and the slivers a change test leaves where the levels meet."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.errors import FailureKind
from cellctl.vision.edge_checks import MAX_EDGE_OFFSET_MM, check_edge_offsets, edge_offset_pair
from cellctl.vision.shadow import one_camera_shadows, shadow_cleared

MM_PER_PX = 0.39
SIZE = 320
RADIUS = 40.0


def project(points: np.ndarray) -> np.ndarray:
    """Table (x, y, z) mm -> pixels, straight from above (the height does not move a point here)."""
    return points[:, :2] / MM_PER_PX + SIZE / 2


def _radius_and_angle() -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    x, y = (u - SIZE / 2) * MM_PER_PX, (v - SIZE / 2) * MM_PER_PX
    return np.hypot(x, y), np.arctan2(y, x)


def _texture(seed: int, spread: float) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0.0, 1.0, (SIZE, SIZE)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 1.2)
    return smooth * (spread / float(smooth.std()))


def scene(rim: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(current, reference, changed): a table at ~100 DN with a texture of 6 DN; a bright sole of RADIUS mm with a
    texture of its own. On the side y > 0 (the shadow's side) the table lies at 0.55 of its light from the sole
    to 48 mm and at 0.8 to 60 mm, and the mask holds a sliver 1.5-3 mm beyond the sole (the table the change test
    did not accept there) behind 1.5 mm of shadowed table it did. rim: instead, no shadow, and the sole's outer
    2 mm is a dark rim (as dark as the shadow, without the table's texture) whose inner mm the mask missed."""
    r, angle = _radius_and_angle()
    reference = 100.0 + _texture(1, 6.0)
    light = np.ones_like(r)
    side = np.sin(angle) > 0.2  # the shadow's side; its two levels meet (the slivers) away from its ends
    middle = np.sin(angle) > 0.6
    if not rim:
        light[side & (r < 48.0)] = 0.55
        light[side & (r >= 48.0) & (r < 60.0)] = 0.8
    current = reference * light
    sole = r < RADIUS
    current[sole] = 200.0 + _texture(2, 5.0)[sole]
    changed = sole.copy()
    if rim:
        band = (r >= RADIUS - 2.0) & (r < RADIUS)
        current[band] = 55.0 + _texture(3, 3.0)[band]
        changed &= ~(side & (r >= RADIUS - 2.0) & (r < RADIUS - 1.0))  # the rim's inner mm missed
    else:
        changed |= middle & (r >= RADIUS + 1.5) & (r < RADIUS + 3.0)
    current = current + np.random.default_rng(4).normal(0.0, 1.0, current.shape)
    return current.astype(np.float32), reference.astype(np.float32), changed


def _ring(radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    angle = np.linspace(0.0, 2 * np.pi, len(radius), endpoint=False)
    outward = np.column_stack([np.cos(angle), np.sin(angle)])
    return radius[:, None] * outward, outward


def _offsets(outline: np.ndarray, outward: np.ndarray, changed: np.ndarray) -> np.ndarray:
    innermost, outermost = edge_offset_pair(outline, outward, np.zeros(len(outline)), changed, project)
    return np.where(np.isfinite(outermost), outermost, innermost)


def _cleared(outline: np.ndarray, outward: np.ndarray, images: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    current, reference, changed = images
    return shadow_cleared(changed, current, reference, outline, outward, [np.zeros(len(outline))], project)


N_POINTS = int(2 * np.pi * RADIUS)


def test_the_slivers_of_a_shadow_are_cleared_and_the_true_outline_passes() -> None:
    images = scene()
    outline, outward = _ring(np.full(N_POINTS, RADIUS))
    raw = _offsets(outline, outward, images[2])
    problem = check_edge_offsets([raw])
    assert problem is not None and "beyond" in problem.reason  # the sliver reads as the sole's edge
    cleared = _cleared(outline, outward, images)
    assert np.count_nonzero(images[2] & ~cleared) > 100
    r, _ = _radius_and_angle()
    assert not np.any((images[2] & ~cleared)[r < RADIUS])  # nothing of the sole
    found = _offsets(outline, outward, cleared)
    assert np.nanmax(np.abs(found)) <= 0.5
    assert check_edge_offsets([found]) is None


def test_an_outline_short_of_the_edge_in_the_shadow_is_still_refused() -> None:
    images = scene()
    radius = np.full(N_POINTS, RADIUS)
    angle = np.linspace(0.0, 2 * np.pi, N_POINTS, endpoint=False)
    short = (angle > 1.3) & (angle < 1.8)  # 20 mm of outline on the shadow's side
    radius[short] -= 1.5
    outline, outward = _ring(radius)
    found = _offsets(outline, outward, _cleared(outline, outward, images))
    assert np.nanmedian(found[short]) == pytest.approx(1.5, abs=0.3)
    problem = check_edge_offsets([found])
    assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT and "beyond" in problem.reason
    assert float(problem.reason.split(" lies ")[1].split(" mm")[0]) > MAX_EDGE_OFFSET_MM


def test_a_dark_rim_beyond_a_missed_band_is_not_taken_for_a_shadow() -> None:
    # The outline stops where the mask's miss begins, 2 mm short of the edge: the rim's outer mm beyond the missed
    # one is as dark as a shadow and detached, but it has none of the table's texture.
    images = scene(rim=True)
    outline, outward = _ring(np.full(N_POINTS, RADIUS - 2.0))
    cleared = _cleared(outline, outward, images)
    assert np.count_nonzero(images[2] & ~cleared) == 0
    problem = check_edge_offsets([_offsets(outline, outward, cleared)])
    assert problem is not None and "beyond" in problem.reason


def test_a_camera_is_read_without_its_shadow_samples_only_where_the_other_confirms_the_outline() -> None:
    raw = (np.array([2.5, 2.5, 2.5, 0.1]), np.array([0.2, 1.4, np.nan, 0.3]))
    cleared = (np.array([0.1, 0.1, 0.1, 0.1]), np.array([0.2, 0.2, 0.2, 0.2]))
    left, right = one_camera_shadows(raw, cleared)
    # left: the right camera confirms the outline at point 0 only (1.4 mm beyond: no; no edge read: no)
    assert left.tolist() == [0.1, 2.5, 2.5, 0.1]
    # right: the left camera's raw reading is beyond the outline at points 0-2: its own stays
    np.testing.assert_array_equal(right, [0.2, 1.4, np.nan, 0.2])
