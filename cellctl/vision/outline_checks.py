"""The outline's self-checks on a reconstruction (docs/measurements.md, Validity): the evidence each check
of cellctl.vision.checks and cellctl.vision.edge_checks compares the outline with, taken from the
reconstruction (depth step, both cameras' change masks, the height map) and the projections into the
rectified images.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.stereo.pointgrid import PointGrid
from cellctl.vision import rounded_edge
from cellctl.vision.checks import (
    OUTLINE_OUTSIDE_MM,
    UNTAUGHT_OUTSIDE_PX,
    CheckFailure,
    check_outline_depth,
    check_outline_right,
    hidden_from,
)
from cellctl.vision.closed_path import outward_normals, resample_closed
from cellctl.vision.edge_checks import (
    WALL_HEIGHT_INSET_MM,
    WALL_HEIGHT_RADIUS_MM,
    check_edge_offsets,
    check_edge_profile,
    check_outline_notch,
    check_outline_spur,
    check_steep_wall,
    check_wall_height,
)
from cellctl.vision.edge_step import check_inner_step, inner_steps, step_profiles
from cellctl.vision.footprint import Footprint
from cellctl.vision.image_edge import (
    Camera,
    PlacedOutline,
    camera_readings,
    edge_heights,
    mm_per_pixel,
    projections,
    stereo_offsets,
    table_level,
    unpaired,
)
from cellctl.vision.reconstruction import Reconstruction
from cellctl.vision.shadow import one_camera_shadows, shadow_cleared
from cellctl.vision.surface import SoleSurface
from cellctl.vision.wall_foot import feet_confirmed, read_feet, wall_inside

SHADOW_CLEARED = True  # the edge-offset check reads the masks without detached shadow slivers (vision.shadow)


def outline_problem(reconstruction: Reconstruction, placed: PlacedOutline, surface: SoleSurface) -> CheckFailure | None:
    """The outline's self-checks: against the depth step, and against the right image when a table is taught.
    The placed outline (image_edge.onto_image_edge) also says where one camera alone placed it (a notch the
    other's mask left): the edge-offset check reads those points by that camera."""
    ring = resample_closed(placed.outline, 1.0)
    outward = outward_normals(ring)
    heights = height_map(reconstruction)
    if reconstruction.raised is not None and reconstruction.measured_cells is not None:
        # Untaught, the colour test's edge is also held to the nearer distance (checks.UNTAUGHT_OUTSIDE_PX).
        tests = [(OUTLINE_OUTSIDE_MM, False)]  # (distance outside, supplementary)
        stereo = reconstruction.calibration is not None and reconstruction.camera_to_table is not None
        if reconstruction.taught is None and stereo:  # (a true depth map has no pixels, and no fattening)
            tests.append((UNTAUGHT_OUTSIDE_PX * mm_per_pixel(reconstruction), True))
        for outside_mm, supplementary in tests:
            hidden = None
            if reconstruction.camera_to_table is not None:
                left_centre = reconstruction.camera_to_table[:3, 3]
                hidden = hidden_from(ring + outside_mm * outward, left_centre, heights)
            problem = check_outline_depth(
                ring,
                outward,
                reconstruction.raised,
                reconstruction.measured_cells,
                reconstruction.footprint,
                hidden,
                outside_mm,
                supplementary=supplementary,
            )
            if problem is not None:
                return problem
    problem = check_edge_profile(
        ring, outward, heights, lambda: rounded_edge.detail(reconstruction, ring, outward, heights)
    )
    if problem is not None:
        return problem
    problem = _check_outline_images(reconstruction, ring, outward, surface, heights, placed.cameras_at(ring))
    if problem is not None:
        return problem
    # A wall the checks above let through (measured all the way down to its foot) still puts the glue line on
    # its steep face.
    problem = check_steep_wall(ring, outward, heights)
    if problem is not None:
        return problem
    # Last: a short notch or spur both cameras' masks share passes every check above; the outline's shape shows it.
    problem = check_outline_notch(ring)
    if problem is not None:
        return problem
    return check_outline_spur(ring)


def wall_problem(placed: PlacedOutline, surface: SoleSurface) -> CheckFailure | None:
    """A wall too low all round to show whether it leans out (edge_checks.check_wall_height): read on the outline
    resampled every 1 mm, as the outline's checks read it."""
    ring = resample_closed(placed.outline, 1.0)
    inside = ring - WALL_HEIGHT_INSET_MM * outward_normals(ring)
    return check_wall_height(surface.coarse_heights(inside, WALL_HEIGHT_RADIUS_MM))


def _check_outline_images(
    reconstruction: Reconstruction,
    ring: np.ndarray,
    outward: np.ndarray,
    surface: SoleSurface,
    heights: Callable[[np.ndarray], np.ndarray],
    one_camera: np.ndarray,
) -> CheckFailure | None:
    """The outline against both cameras' change masks (taught table only): the right image, then the edge; then
    against the raw images' own step at it (cellctl.vision.edge_step), which a band both masks share hides from them.
    one_camera: per ring point the camera whose reading alone counts for the edge offsets there (-1: both)."""
    changed_right = reconstruction.changed_right
    if changed_right is None or reconstruction.calibration is None:
        return None
    (left_pixel, left_centre), (right_pixel, right_centre) = projections(reconstruction)
    edge_height = edge_heights(surface, ring, outward)
    level = table_level(reconstruction)
    problem = check_outline_right(ring, outward, edge_height, changed_right, right_pixel, right_centre, heights, level)
    if problem is not None or reconstruction.changed_left is None:
        return problem
    # Per camera, its silhouette's edge at the height where it lies (cellctl.vision.image_edge.stereo_offsets):
    # the top edge from the inward side of a wall; from the outward side the foot on the table or the top edge
    # where the wall is lit so that it hardly differs from the table, whichever the other camera confirms.
    # Read twice: the innermost of equally good steps, then the outermost (edge_checks.edge_offset_pair): where
    # evidence is missing (changed pixels excused on table-level cells) neither reading may clear the outline.
    cameras = (
        (reconstruction.changed_left, left_pixel, left_centre),
        (changed_right, right_pixel, right_centre),
    )
    images = (
        None
        if reconstruction.rectified is None or reconstruction.taught is None
        else (reconstruction.rectified, (reconstruction.taught.left, reconstruction.taught.right))
    )
    inner, outer = _offsets(ring, outward, edge_height, cameras, level, images)  # both readings from one sampling
    inner, outer = by_one_camera(inner, one_camera), by_one_camera(outer, one_camera)
    problem = _edge_offsets_problem(inner, outer, ring)
    if problem is None:
        return None if images is None else _inner_step_problem(ring, outward, edge_height, images[0], cameras)
    if not SHADOW_CLEARED or images is None:
        return problem
    # Refused: a cast shadow's slivers beside the sole that one camera's mask shows and the other's does not
    # (cellctl.vision.shadow) are read again without them. Only here: an outline the masks as they are pass is
    # passed as before, at no cost to the cycle.
    levels = [np.zeros(len(ring)), np.maximum(edge_height, 0.0)]
    cleared = tuple(
        (shadow_cleared(changed, current, reference, ring, outward, levels, pixel), pixel, centre)
        for (changed, pixel, centre), current, reference in zip(cameras, images[0], images[1], strict=True)
    )
    inner_cleared, outer_cleared = (
        by_one_camera(readings, one_camera)
        for readings in _offsets(ring, outward, edge_height, (cleared[0], cleared[1]), level, images)
    )
    problem = _edge_offsets_problem(
        one_camera_shadows(inner, inner_cleared), one_camera_shadows(outer, outer_cleared), ring
    )
    return problem or _inner_step_problem(ring, outward, edge_height, images[0], cameras)


def _inner_step_problem(
    ring: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    current: tuple[np.ndarray, np.ndarray],
    cameras: tuple[Camera, Camera],
) -> CheckFailure | None:
    """The sole's step in both raw images against the outline (cellctl.vision.edge_step), at the top edge's height
    (each camera's silhouette where the sole hides its wall, as a dark band at the foot lies beyond)."""
    level = np.maximum(edge_height, 0.0)
    flags = [
        inner_steps(step_profiles(ring, outward, level, image, pixel))
        for image, (_, pixel, _) in zip(current, cameras, strict=True)
    ]
    return check_inner_step(flags[0], flags[1])


def _offsets(
    ring: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    cameras: tuple[Camera, Camera],
    level: Footprint | None,
    images: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None,
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Both cameras' edge offsets (`stereo_offsets`: innermost, outermost), with their foot readings where the masks
    cannot tell foot from top and the `images` (current and taught grey pairs) show a wall's face about either
    camera's foot reading (cellctl.vision.wall_foot)."""
    readings = camera_readings(ring, outward, edge_height, cameras, level)
    inner, outer = stereo_offsets(ring, outward, edge_height, cameras, level, readings)
    if images is None or not np.any(unpaired(readings)):
        return inner, outer
    wall = [
        wall_inside(current, reference, changed, pixel, ring, outward, reading[0][0], reading[1][0])
        for (changed, pixel, _), current, reference, reading in zip(
            cameras, images[0], images[1], readings, strict=True
        )
    ]
    confirmed = feet_confirmed(readings, wall[0], wall[1])
    return read_feet(inner, readings, confirmed, 0), read_feet(outer, readings, confirmed, 1)


def by_one_camera(readings: tuple[np.ndarray, np.ndarray], one_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both cameras' readings with the other camera's unknown (NaN) where one camera alone placed the outline
    (`one_camera` per point: 0 left, 1 right, -1 neither): a notch that camera filled (image_edge.notch_fill),
    which the other camera's mask shows because its mask has the notch."""
    left, right = readings
    return np.where(one_camera == 1, np.nan, left), np.where(one_camera == 0, np.nan, right)


def _edge_offsets_problem(
    inner: tuple[np.ndarray, np.ndarray], outer: tuple[np.ndarray, np.ndarray], ring: np.ndarray
) -> CheckFailure | None:
    """The edge-offset check on both readings (stereo_offsets) along the outline `ring`: the innermost, then the
    outermost."""
    problem = check_edge_offsets(list(inner), ring)
    if problem is not None:
        return problem
    return check_edge_offsets(list(outer), ring)


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
