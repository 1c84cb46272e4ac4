"""The glue line's offset: points snapped onto the line a given distance inside a footprint's edge, also at
a sharp pointed end where a smoothed raster line is pulled inwards."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.closed_path import smooth_closed
from cellctl.vision.footprint import Footprint, snap_to_inset
from cellctl.vision.measurement import GLUE_EDGE_CLOSE_MM

CELL = 0.25


def wedge_polygon() -> np.ndarray:
    """A 35 degree pointed end (tip at x = 100 mm) on a 60 mm wide body, table mm, counter-clockwise."""
    half = np.radians(17.5)
    run = 30.0 / np.tan(half)
    return np.array([[100.0, 0.0], [100.0 - run, 30.0], [-60.0, 30.0], [-60.0, -30.0], [100.0 - run, -30.0]])


def raster(polygon: np.ndarray) -> Footprint:
    """Cells whose centres lie inside the (convex, counter-clockwise) polygon."""
    origin = (-70.0, -40.0)
    rows, cols = np.mgrid[0 : int(80 / CELL), 0 : int(180 / CELL)]
    x, y = origin[0] + (cols + 0.5) * CELL, origin[1] + (rows + 0.5) * CELL
    inside = np.ones(x.shape, bool)
    for (x0, y0), (x1, y1) in zip(polygon, np.roll(polygon, -1, axis=0), strict=True):
        inside &= (x1 - x0) * (y - y0) - (y1 - y0) * (x - x0) >= 0
    return Footprint(inside.astype(np.uint8), origin, CELL)


def true_inset(polygon: np.ndarray, xy: np.ndarray) -> np.ndarray:
    contour = polygon.astype(np.float32).reshape(-1, 1, 2)
    return np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in xy])


def test_a_smoothed_glue_line_is_snapped_back_onto_its_offset_at_a_pointed_tip() -> None:
    polygon = wedge_polygon()
    footprint = raster(polygon)
    line = smooth_closed(footprint.eroded(2.0 + 0.5 * CELL).outline(), 2.0)
    before = np.abs(true_inset(polygon, line) - 2.0)
    assert before.max() > 0.5  # the smoothing rounds the corner inwards: what the snapping is for
    snapped = snap_to_inset(footprint, line, 2.0)
    after = np.abs(true_inset(polygon, snapped) - 2.0)
    assert after.max() < 0.2, after.max()
    # Points that were on the offset stay there (along the straight sides).
    straight = before < 0.05
    assert np.abs(snapped[straight] - line[straight]).max() < 0.15


def test_points_on_the_medial_axis_are_left_alone() -> None:
    footprint = raster(np.array([[-20.0, -10.0], [20.0, -10.0], [20.0, 10.0], [-20.0, 10.0]]))
    ridge = np.array([[0.0, 0.0], [5.0, 0.0]])  # 10 mm inside, on the ridge of the distance field
    np.testing.assert_allclose(snap_to_inset(footprint, ridge, 2.0), ridge, atol=1e-9)


def test_a_polygon_filled_on_the_cells_marks_exactly_the_cells_whose_centres_it_holds() -> None:
    polygon = wedge_polygon()
    exact = raster(polygon)
    filled = Footprint(np.zeros_like(exact.mask), exact.origin, CELL).filled(polygon)
    rows, cols = np.nonzero(filled.mask != exact.mask)
    centres = np.column_stack([exact.origin[0] + (cols + 0.5) * CELL, exact.origin[1] + (rows + 0.5) * CELL])
    assert np.abs(true_inset(polygon, centres)).max(initial=0.0) < 0.02  # only ties on the edge differ
    shifted = Footprint(np.zeros_like(exact.mask), exact.origin, CELL).filled(polygon + np.array([CELL, 0.0]))
    assert np.count_nonzero(shifted.mask != exact.mask) > 100


def test_a_polygon_crossing_the_rasters_edges_marks_the_cells_within_it() -> None:
    """Filled within the polygon's box clipped to the raster: a polygon reaching past the raster's edges (here its
    tip and its back) marks the raster's cells it holds, the same as a raster drawn by cell centres; one wholly
    outside marks none."""
    polygon = wedge_polygon() + np.array([-25.0, -15.0])  # the back crosses x = -70 mm, a side y = -40 mm
    exact = raster(polygon)
    filled = Footprint(np.zeros_like(exact.mask), exact.origin, CELL).filled(polygon)
    assert exact.mask[:, 0].any() and exact.mask[0, :].any()  # it does reach the edges
    rows, cols = np.nonzero(filled.mask != exact.mask)
    centres = np.column_stack([exact.origin[0] + (cols + 0.5) * CELL, exact.origin[1] + (rows + 0.5) * CELL])
    assert len(rows) < 20 and np.abs(true_inset(polygon, centres)).max(initial=0.0) < 0.03  # ties on the edge
    away = Footprint(np.zeros_like(exact.mask), exact.origin, CELL).filled(polygon + np.array([500.0, 0.0]))
    assert not away.mask.any()


def test_closing_fills_a_narrow_dent_and_keeps_the_rest_of_the_edge_and_a_pointed_tip() -> None:
    whole = raster(wedge_polygon())
    dented = Footprint(whole.mask.copy(), whole.origin, whole.cell_mm)
    # A dent 1.5 mm deep and 6 mm wide in the straight side at y = +30 mm (cells are 0.25 mm).
    row = int((30.0 - 1.5 - whole.origin[1]) / CELL)
    col = int((-20.0 - whole.origin[0]) / CELL)
    dented.mask[row:, col : col + int(6.0 / CELL)] = 0
    radius = GLUE_EDGE_CLOSE_MM
    assert np.array_equal(whole.closed(radius).mask, whole.mask)  # convex: the edge and the 35 degree tip stay
    closed = dented.closed(radius)
    assert not np.any(closed.mask & ~whole.mask)  # nothing beyond the true edge
    # A disc of radius R dips R - sqrt(R^2 - 3^2) into a 6 mm wide dent's mouth: only that sliver stays open.
    sliver = radius - np.sqrt(radius**2 - 9.0)
    missing_rows = np.nonzero(whole.mask & ~closed.mask)[0]
    assert missing_rows.size and whole.origin[1] + (missing_rows.min() + 0.5) * CELL > 30.0 - sliver - CELL


def test_centres_are_the_marked_cells_centres_in_raster_order() -> None:
    """Footprint.centres (flat indices) against the two-index formulation it replaced, value for value."""
    rng = np.random.default_rng(11)
    for shape, share, cell in (((1, 1), 1.0, 0.5), ((5, 7), 0.0, 0.25), ((40, 30), 0.3, 0.5), ((1, 300), 0.9, 1.0)):
        mask = (rng.random(shape) < share).astype(np.uint8)
        footprint = Footprint(mask, (float(rng.uniform(-50, 50)), float(rng.uniform(-50, 50))), cell)
        rows, cols = np.nonzero(mask)
        expected = np.column_stack(
            [footprint.origin[0] + (cols + 0.5) * cell, footprint.origin[1] + (rows + 0.5) * cell]
        )
        centres = footprint.centres()
        assert centres.shape == expected.shape and np.array_equal(centres, expected)
