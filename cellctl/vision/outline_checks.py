"""The outline's self-checks on a reconstruction (docs/measurements.md, Validity): the evidence each check
of cellctl.vision.checks and cellctl.vision.edge_checks compares the outline with, taken from the
reconstruction (depth step, both cameras' change masks, the height map) and the projections into the
rectified images.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.stereo.kernels import PointGrid
from cellctl.vision.checks import (
    OUTLINE_OUTSIDE_MM,
    CheckFailure,
    check_outline_depth,
    check_outline_right,
    hidden_from,
)
from cellctl.vision.closed_path import outward_normals, resample_closed
from cellctl.vision.edge_checks import check_edge_offsets, check_edge_profile, edge_offsets
from cellctl.vision.footprint import Footprint
from cellctl.vision.reconstruction import Reconstruction
from cellctl.vision.surface import SoleSurface


def outline_problem(reconstruction: Reconstruction, outline: np.ndarray, surface: SoleSurface) -> CheckFailure | None:
    """The outline's self-checks: against the depth step, and against the right image when a table is taught."""
    ring = resample_closed(outline, 1.0)
    outward = outward_normals(ring)
    heights = height_map(reconstruction)
    if reconstruction.raised is not None and reconstruction.measured_cells is not None:
        hidden = None
        if reconstruction.camera_to_table is not None:
            left_centre = reconstruction.camera_to_table[:3, 3]
            hidden = hidden_from(ring + OUTLINE_OUTSIDE_MM * outward, left_centre, heights)
        problem = check_outline_depth(
            ring, outward, reconstruction.raised, reconstruction.measured_cells, reconstruction.footprint, hidden
        )
        if problem is not None:
            return problem
    problem = check_edge_profile(ring, outward, heights)
    if problem is not None:
        return problem
    changed_right, calib = reconstruction.changed_right, reconstruction.calibration
    if changed_right is None or calib is None:
        return None
    to_camera = np.linalg.inv(reconstruction.camera_to_table)
    f, cx, cy, baseline = calib.focal_px, calib.P1[0, 2], calib.P1[1, 2], calib.baseline_mm

    def right_pixel(table: np.ndarray) -> np.ndarray:
        camera = table @ to_camera[:3, :3].T + to_camera[:3, 3]
        return np.column_stack(
            [f * (camera[:, 0] - baseline) / camera[:, 2] + cx, f * camera[:, 1] / camera[:, 2] + cy]
        )

    centre = reconstruction.camera_to_table @ np.array([baseline, 0.0, 0.0, 1.0])
    edge_height = surface.coarse_heights(ring - 3.0 * outward, 3.0)
    edge_height = np.where(np.isfinite(edge_height), edge_height, np.nanmedian(edge_height))
    table_level = None
    if reconstruction.raised is not None and reconstruction.measured_cells is not None:
        table_level = Footprint(
            reconstruction.measured_cells.mask & (1 - reconstruction.raised.mask),
            reconstruction.raised.origin,
            reconstruction.raised.cell_mm,
        )
    problem = check_outline_right(
        ring, outward, edge_height, changed_right, right_pixel, centre[:3], heights, table_level
    )
    if problem is not None or reconstruction.changed_left is None:
        return problem

    def left_pixel(table: np.ndarray) -> np.ndarray:
        camera = table @ to_camera[:3, :3].T + to_camera[:3, 3]
        return np.column_stack([f * camera[:, 0] / camera[:, 2] + cx, f * camera[:, 1] / camera[:, 2] + cy])

    offsets = []
    for changed, to_pixel, camera_centre in (
        (reconstruction.changed_left, left_pixel, reconstruction.camera_to_table[:3, 3]),
        (changed_right, right_pixel, centre[:3]),
    ):
        # From the inward side of a (vertical) wall the silhouette is the top edge, at the edge's height. A
        # camera on the outward side sees the wall, and the change mask ends at its foot on the table, or
        # at the top edge where the wall is lit so that it hardly differs from the table: either is the edge.
        top = edge_offsets(ring, outward, np.maximum(edge_height, 0.0), changed, to_pixel, table_level)
        foot = edge_offsets(ring, outward, np.zeros(len(ring)), changed, to_pixel, table_level)
        sees_wall = np.sum(outward * (camera_centre[:2] - ring), axis=1) > 0
        nearer = np.where(np.abs(np.nan_to_num(foot, nan=np.inf)) < np.abs(np.nan_to_num(top, nan=np.inf)), foot, top)
        offsets.append(np.where(sees_wall, nearer, top))
    return check_edge_offsets(offsets)


HEIGHT_MAP_CELL_MM = 1.0


def height_map(reconstruction: Reconstruction) -> Callable[[np.ndarray], np.ndarray]:
    """Sole height at table points (NaN off the sole): the median of the sole's points per 1 mm cell."""
    points = reconstruction.sole_points
    raster = Footprint.empty_like(points[:, :2], HEIGHT_MAP_CELL_MM)
    # The median of each cell's sorted heights (the upper middle one for an even count), per cell in C.
    cells = PointGrid(points[:, :2], HEIGHT_MAP_CELL_MM, points[:, 2], raster.origin, raster.mask.shape)
    grid = cells.cell_upper_medians().ravel()

    def height(xy: np.ndarray) -> np.ndarray:
        r, c, inside = raster.cells(xy)
        return np.where(inside, grid[r * raster.mask.shape[1] + c], np.nan)

    return height
