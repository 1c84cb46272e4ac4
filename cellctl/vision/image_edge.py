"""The sole's edge placed from the images: the depth-based outline moved onto the edge both cameras'
silhouettes (change masks against the taught table) show, each projected at the height where that camera's
silhouette lies (docs/measurements.md, Footprint), only where depth is silent between the outline and that
edge (`depth_silent`). docs/sole-benchmark.md has what it measured, with and without that guard.

Why the guard: after a move the edge-offset check compares the outline with the masks it was moved onto, so
it can no longer refuse an outward error both masks share (a contact shadow). Such an error lies on the
table, whose texture the matcher measures at table height; the error the move is for (a black top edge's
last mm without depth: where the census window straddles the step along an edge near the epipolar lines, the
sole's and the table's disparities cost alike and the uniqueness test drops both) has no depth at all there.

Off by default (PLACE_EDGE_FROM_IMAGES): the guard holds where the shadowed table keeps its texture (the test's
case), but the matrix's dark cast shadows (2016, 2039: a low side light) leave the table beside the sole
without depth too, and there the guarded placement moved 55 outline points 1.6-3.2 mm past the true edge
(both soles refused by the depth-step check all the same; /work/notes/edge-diag/guard_truth.py). On, it
measures 3 more of the 84 matrix soles and bench --cycle's black sole 2 (docs/sole-benchmark.md, fifth round).

A camera's silhouette is the top edge where the sole hides its wall from it (the wall faces away): there
the edge lies where the silhouette's ray meets the top edge's measured height. Where a camera sees the wall,
its silhouette is the foot or, for a wall lit like the table, the top edge, which one camera cannot tell
apart: the reading nearer the outline is taken. The outline is moved only outward, where both cameras give
an edge, agree, and the move is larger than the edge's own scatter in the images; elsewhere it stays where
the depth put it, and the self-checks judge the result.

The camera projections, the table-level cells and the per-camera reading (`silhouette_offsets`) are also what
the edge-offset check of cellctl.vision.outline_checks reads the images with.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from cellctl.vision.closed_path import outward_normals, resample_closed, smooth_along
from cellctl.vision.edge_checks import EDGE_OFFSET_WINDOW_MM, edge_offsets
from cellctl.vision.footprint import Footprint
from cellctl.vision.reconstruction import Reconstruction
from cellctl.vision.surface import SoleSurface

PLACE_EDGE_FROM_IMAGES = False  # the module docstring says why
EDGE_MOVE_MIN_MM = 0.5  # a sharp edge's offsets scatter by ~0.2 mm in the images: smaller is no evidence
EDGE_MOVE_AGREE_MM = 0.5  # both cameras' local edges this close (a shadow or a texture line fools one mask)
EDGE_MOVE_SMOOTHING_MM = 1.5
# The guard (`depth_silent`): a move must cross ground where depth measured nothing at the table's height, in a
# strip this wide along the outline, up to this far short of the proposed edge (the table is measured from there).
SILENT_STRIP_MM = 1.0
SILENT_SHORT_OF_EDGE_MM = 0.25
SILENT_STEP_MM = 0.125  # half a raster cell


def projections(
    reconstruction: Reconstruction,
) -> tuple[
    tuple[Callable[[np.ndarray], np.ndarray], np.ndarray], tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]
]:
    """Per camera (left, right): table points (N x 3) -> rectified pixels (N x 2), and its centre in the table
    frame. The reconstruction must come from a stereo cloud (a calibration)."""
    calib = reconstruction.calibration
    assert calib is not None
    to_camera = np.linalg.inv(reconstruction.camera_to_table)
    f, cx, cy, baseline = calib.focal_px, calib.P1[0, 2], calib.P1[1, 2], calib.baseline_mm

    def pixel(shift: float) -> Callable[[np.ndarray], np.ndarray]:
        def project(table: np.ndarray) -> np.ndarray:
            camera = table @ to_camera[:3, :3].T + to_camera[:3, 3]
            return np.column_stack(
                [f * (camera[:, 0] - shift) / camera[:, 2] + cx, f * camera[:, 1] / camera[:, 2] + cy]
            )

        return project

    right_centre = (reconstruction.camera_to_table @ np.array([baseline, 0.0, 0.0, 1.0]))[:3]
    return (pixel(0.0), reconstruction.camera_to_table[:3, 3]), (pixel(baseline), right_centre)


def table_level(reconstruction: Reconstruction) -> Footprint | None:
    """Cells whose measured points lie at the table's height (measured, not raised), if the depth step is known."""
    raised, measured = reconstruction.raised, reconstruction.measured_cells
    if raised is None or measured is None:
        return None
    return Footprint(measured.mask & (1 - raised.mask), raised.origin, raised.cell_mm)


def edge_heights(surface: SoleSurface, ring: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """The sole's height near each outline point (3 mm inside; the median of the others where none)."""
    edge_height = surface.coarse_heights(ring - 3.0 * outward, 3.0)
    return np.where(np.isfinite(edge_height), edge_height, np.nanmedian(edge_height))


def silhouette_offsets(
    ring: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    changed: np.ndarray,
    to_pixel: Callable[[np.ndarray], np.ndarray],
    centre: np.ndarray,
    table_level: Footprint | None = None,
    outermost: bool = False,
) -> np.ndarray:
    """Where one camera's silhouette puts the edge, in mm along the outward normal from each outline point.

    A silhouette gives a ray, not a point: the edge lies where the ray meets the height of whatever part of the
    sole makes the silhouette. Where the sole hides the wall from the camera, that is the top edge, at its
    measured height. Where the camera sees the wall it is the wall's foot on the table, or the top edge again if
    the wall is lit like the table (no change); one camera cannot tell the two apart (the same ray at two
    heights), so there the reading nearer the outline is taken (the edge-offset check's rule): with outward
    moves only, the smaller claim. outermost: as in edge_checks.edge_offsets (for the check, not for placing).
    """
    sees_wall = np.sum(outward * (centre[:2] - ring), axis=1) > 0
    foot = edge_offsets(ring, outward, np.zeros(len(ring)), changed, to_pixel, table_level, outermost)
    top = edge_offsets(ring, outward, np.maximum(edge_height, 0.0), changed, to_pixel, table_level, outermost)
    nearer = np.where(np.abs(np.nan_to_num(foot, nan=np.inf)) < np.abs(np.nan_to_num(top, nan=np.inf)), foot, top)
    return np.where(sees_wall, nearer, top)


def _local(offsets: np.ndarray) -> np.ndarray:
    """Running median over EDGE_OFFSET_WINDOW_MM of outline (points 1 mm apart); NaN without enough."""
    half = EDGE_OFFSET_WINDOW_MM // 2
    window = np.stack([np.roll(offsets, s) for s in range(-half, half + 1)])
    enough = np.isfinite(window).sum(axis=0) > half
    with warnings.catch_warnings():  # all-NaN windows are left out by `enough`
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.where(enough, np.nanmedian(window, axis=0), np.nan)


def edge_shift(
    left: np.ndarray, right: np.ndarray, silent: Callable[[np.ndarray], np.ndarray] | None = None
) -> np.ndarray:
    """How far to move each outline point out along its normal: both cameras' local edge where they agree
    within EDGE_MOVE_AGREE_MM and their mean is more than EDGE_MOVE_MIN_MM beyond the outline, else 0;
    smoothed along the outline. Never inward: the change masks' own errors (a wall lit like the table, the
    change test's blur at a top edge) put the edge inside the sole in both cameras alike, so their agreement
    on an inward edge is no evidence (the self-check refuses there instead).

    silent (proposed moves -> bool per point): whether depth is silent over each move (`depth_silent`); where
    it is not, the point stays, also after the smoothing, so the edge-offset check still judges it there."""
    local_left, local_right = _local(left), _local(right)
    mean = 0.5 * (local_left + local_right)
    move = (np.abs(local_left - local_right) <= EDGE_MOVE_AGREE_MM) & (mean > EDGE_MOVE_MIN_MM)
    proposed = np.where(move, mean, 0.0)
    if silent is None:
        return smooth_along(proposed, EDGE_MOVE_SMOOTHING_MM)
    allowed = move & silent(proposed)
    return np.where(allowed, smooth_along(np.where(allowed, mean, 0.0), EDGE_MOVE_SMOOTHING_MM), 0.0)


def depth_silent(ring: np.ndarray, outward: np.ndarray, table_points: Footprint) -> Callable[[np.ndarray], np.ndarray]:
    """Per outline point and proposed move: True where depth measured no point at the table's height between
    the outline and the proposed edge (a strip SILENT_STRIP_MM wide, up to SILENT_SHORT_OF_EDGE_MM short of it).

    That is the case the move is for: a weakly textured top edge whose last mm has no depth (the matcher
    cannot tell the top's disparity from the table's where its window straddles the step), so the depth step
    ends short of the edge both masks show. An outward error both masks share lies on the table instead (a
    contact shadow, a dark stain at the foot): the matcher measures the table's texture there at table
    height, and the point is not moved (the edge-offset check then refuses it). `table_points` are the raw
    cells with such points, not the dilated `measured_cells`, which would hide a 1 mm gap."""
    tangent = np.column_stack([-outward[:, 1], outward[:, 0]])
    across = np.arange(-0.5 * SILENT_STRIP_MM, 0.5 * SILENT_STRIP_MM + 1e-9, SILENT_STEP_MM)

    def silent(proposed: np.ndarray) -> np.ndarray:
        result = np.zeros(len(ring), bool)
        moving = np.flatnonzero(proposed > 0)
        if moving.size == 0:
            return result
        reach = np.maximum(proposed[moving] - SILENT_SHORT_OF_EDGE_MM, SILENT_STEP_MM)
        along = np.arange(0.0, float(reach.max()) + 1e-9, SILENT_STEP_MM)
        xy = (
            ring[moving, None, None]
            + along[None, :, None, None] * outward[moving, None, None]
            + across[None, None, :, None] * tangent[moving, None, None]
        )  # moving x along x across x 2
        row, col, inside = table_points.cells(xy.reshape(-1, 2))
        shape = xy.shape[:3]
        within = np.broadcast_to((along[None, :] <= reach[:, None] + 1e-9)[:, :, None], shape)
        table = table_points.mask[row, col].reshape(shape).astype(bool) | ~inside.reshape(shape)
        result[moving] = ~np.any(table & within, axis=(1, 2))
        return result

    return silent


def onto_image_edge(reconstruction: Reconstruction, outline: np.ndarray, surface: SoleSurface) -> np.ndarray:
    """The outline (closed, table mm) moved onto the edge both cameras show (1 mm spacing), or as it was."""
    changed_left, changed_right = reconstruction.changed_left, reconstruction.changed_right
    if not PLACE_EDGE_FROM_IMAGES or changed_left is None or changed_right is None:
        return outline
    if reconstruction.calibration is None or reconstruction.table_points is None:
        return outline  # no guard without the raw depth cells: the check judges the outline as it is
    ring = resample_closed(outline, 1.0)
    outward = outward_normals(ring)
    if not np.any(np.isfinite(surface.coarse_heights(ring - 3.0 * outward, 3.0))):
        return outline
    edge_height = edge_heights(surface, ring, outward)
    level = table_level(reconstruction)
    left, right = (
        silhouette_offsets(ring, outward, edge_height, changed, to_pixel, centre, level)
        for changed, (to_pixel, centre) in zip((changed_left, changed_right), projections(reconstruction), strict=True)
    )
    shift = edge_shift(left, right, depth_silent(ring, outward, reconstruction.table_points))
    if not np.any(shift):
        return outline
    return ring + shift[:, None] * outward
