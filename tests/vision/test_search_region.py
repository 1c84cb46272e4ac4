"""The search region: where the full-resolution match looks, from a coarse map and the table plane.

Synthetic coarse maps (a table plane and a box standing on it) check the geometry; one rendered sole
checks that the region's result is the whole pair's, and that the shortcut steps aside when it cannot be
trusted.
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.sim.rig import default_rig
from cellctl.sim.scene import SoleScene
from cellctl.vision.measurement import measure_sole
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.search_region import (
    COARSE_SCALE,
    SearchRegion,
    coarse_range,
    find_region,
    plane_disparity,
)
from cellctl.vision.table import TablePlane

RIG = default_rig()
# A table 550 mm below the left camera, tilted a little: its disparity varies across the view.
TILTED = TablePlane(np.array([0.02, -0.03, -1.0]) / np.linalg.norm([0.02, -0.03, -1.0]), 550.0)
FULL_RANGE = (130, 60)


def coarse_map(plane: TablePlane, box: tuple[int, int, int, int] | None, box_height_mm: float) -> np.ndarray:
    """Coarse disparities (coarse px) of the plane, with a box (x0, y0, x1, y1, full-resolution px) raised."""
    width, height = RIG.image_size
    ys, xs = np.mgrid[0 : height // COARSE_SCALE, 0 : width // COARSE_SCALE]
    fx, fy = (xs + 0.5) * COARSE_SCALE - 0.5, (ys + 0.5) * COARSE_SCALE - 0.5
    disparity = plane_disparity(RIG, plane, fx, fy)
    if box is not None:
        x0, y0, x1, y1 = box
        inside = (fx >= x0) & (fx < x1) & (fy >= y0) & (fy < y1)
        disparity[inside] = plane_disparity(RIG, plane, fx, fy, box_height_mm)[inside]
    return (disparity / COARSE_SCALE).astype(np.float32)


def test_plane_disparity_reprojects_onto_the_plane() -> None:
    x, y = np.array([100.0, 640.0, 1200.0]), np.array([80.0, 512.0, 1000.0])
    for height in (0.0, 40.0):
        d = plane_disparity(RIG, TILTED, x, y, height)
        homogeneous = np.column_stack([x, y, d, np.ones(3)]) @ RIG.Q.T
        points = homogeneous[:, :3] / homogeneous[:, 3:]
        assert np.allclose(TILTED.heights(points), height, atol=1e-6)


def test_the_region_covers_the_object_with_table_around_it_and_its_band_from_table_to_top() -> None:
    box = (400, 300, 900, 560)
    region, why = find_region(RIG, TILTED, coarse_map(TILTED, box, 35.0), FULL_RANGE)
    assert region is not None, why
    margin = 25.0 * RIG.focal_px / TILTED.offset  # REGION_MARGIN_MM in pixels
    assert region.x0 <= box[0] - margin and region.y0 <= box[1] - margin
    assert region.x1 >= box[2] + margin and region.y1 >= box[3] + margin
    assert region.pixels < 0.5 * RIG.image_size[0] * RIG.image_size[1]  # not the whole view
    corners_x, corners_y = (
        np.array([region.x0, region.x1, region.x0, region.x1]),
        np.array([region.y0] * 2 + [region.y1] * 2),
    )
    table = plane_disparity(RIG, TILTED, corners_x, corners_y)
    top = plane_disparity(RIG, TILTED, corners_x, corners_y, 35.0)
    assert region.shift <= table.min() - 1
    assert region.shift + region.num_disparities - 1 >= top.max() + 1
    assert region.num_disparities < FULL_RANGE[1] / 2  # a 35 mm object needs far fewer than the full range


def test_scattered_coarse_mismatches_do_not_widen_the_region() -> None:
    box = (500, 400, 800, 600)
    clean, _ = find_region(RIG, TILTED, coarse_map(TILTED, box, 30.0), FULL_RANGE)
    noisy_map = coarse_map(TILTED, box, 30.0)
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, noisy_map.shape[0], 40), rng.integers(0, noisy_map.shape[1], 40)
    noisy_map[rows, cols] += 10.0  # single coarse pixels far above the table
    noisy, _ = find_region(RIG, TILTED, noisy_map, FULL_RANGE)
    assert clean is not None and noisy is not None
    assert (noisy.x0, noisy.y0, noisy.x1, noisy.y1) == (clean.x0, clean.y0, clean.x1, clean.y1)


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ("moved", "off the taught plane"),
        ("empty", "nothing above the table"),
        ("unmeasured", "measured too little"),
    ],
)
def test_no_region_when_the_shortcut_cannot_be_trusted(change: str, reason: str) -> None:
    box = None if change == "empty" else (500, 400, 800, 600)
    coarse = coarse_map(TILTED, box, 30.0)
    if change == "moved":  # the table 20 mm lower than taught
        coarse = coarse_map(TablePlane(TILTED.normal, TILTED.offset + 20.0), box, 30.0)
    if change == "unmeasured":
        coarse[:] = np.nan
    region, why = find_region(RIG, TILTED, coarse, FULL_RANGE)
    assert region is None and reason in why


def test_the_crop_pair_shifts_the_right_image_by_the_band_start() -> None:
    left = np.arange(40 * 60, dtype=np.uint16).reshape(40, 60).astype(np.uint8)
    right = np.roll(left, -7, axis=1)  # disparity 7 everywhere
    region = SearchRegion(20, 5, 50, 30, shift=5, num_disparities=8, image_size=(60, 40))
    crop_left, crop_right = region.crop_pair(left, right)
    assert crop_left.shape == crop_right.shape == (25, 30)
    assert np.array_equal(crop_right, right[5:30, 15:45])
    early = SearchRegion(2, 5, 50, 30, shift=5, num_disparities=8, image_size=(60, 40))
    _, padded = early.crop_pair(left, right)  # starts 3 px left of the image: replicated border
    assert padded.shape == (25, 48) and np.array_equal(padded[:, 3:], right[5:30, :45])
    assert np.array_equal(padded[:, 0], right[5:30, 0])


def test_only_region_sides_inside_the_image_can_cut_the_sole() -> None:
    region = SearchRegion(0, 100, 600, 400, shift=150, num_disparities=24, image_size=(1280, 1024))
    assert not region.cuts(np.array([[1.0, 250.0]]), margin_px=30)  # near x0 = 0: the image's own border
    assert region.cuts(np.array([[590.0, 250.0]]), margin_px=30)  # near x1, inside the image
    assert region.cuts(np.array([[300.0, 110.0]]), margin_px=30)
    assert not region.cuts(np.array([[300.0, 250.0]]), margin_px=30)


def test_coarse_range_covers_the_full_range() -> None:
    low, num = coarse_range(*FULL_RANGE)
    assert low * COARSE_SCALE <= FULL_RANGE[0]
    assert (low + num - 1) * COARSE_SCALE >= FULL_RANGE[0] + FULL_RANGE[1] - 1


@pytest.mark.slow
def test_a_sole_measured_in_its_region_matches_the_whole_pair() -> None:
    scene = SoleScene.random(3, "white", RIG)
    empty, pair = scene.render_empty(), scene.render()
    taught = SoleReconstructor(RIG).teach(empty.left, empty.right)
    focused = SoleReconstructor(RIG, taught=taught)
    whole = SoleReconstructor(RIG, taught=taught, search_region=False)
    in_region = measure_sole(focused.reconstruct(pair.left, pair.right))
    assert focused.last_region is not None, focused.last_fallback
    assert focused.last_region.pixels < 0.6 * RIG.image_size[0] * RIG.image_size[1]
    reference = measure_sole(whole.reconstruct(pair.left, pair.right))
    assert in_region.valid and reference.valid, (in_region.reason, reference.reason)
    for name in ("length_mm", "heel_height_mm", "toe_height_mm"):
        assert abs(getattr(in_region, name) - getattr(reference, name)) < 0.1, name
    # A table that is not where it was taught: the whole pair is matched, as without a taught table.
    moved = SoleReconstructor(RIG, table_plane=TablePlane(taught.plane.normal, taught.plane.offset + 20.0))
    moved.reconstruct(pair.left, pair.right)
    assert moved.last_region is None and "off the taught plane" in moved.last_fallback
