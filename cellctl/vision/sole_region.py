"""Where the sole is in one measured cloud: the filters and checks a segmentation run applies to it.

Each function reads the cloud (and the taught table) and returns indices, masks or a verdict; the run's
order and its shared state stay in cellctl.vision.segmentation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
import open3d as o3d

from cellctl.errors import FailureKind
from cellctl.stereo.kernels import disc_dilate, mark_pixels
from cellctl.vision.change import ChangeTest
from cellctl.vision.cloud import StereoCloud
from cellctl.vision.edge_blur import soft_edges
from cellctl.vision.footprint import Footprint
from cellctl.vision.outliers import ISOLATED_SPACINGS, inliers_by_mean, mean_neighbour_distances
from cellctl.vision.shadow_band import shadow_band
from cellctl.vision.table import TABLE_INLIER_MM, TableDisparity, TablePlane
from cellctl.vision.teach import TaughtTable
from cellctl.vision.workers import worker

BORDER_MARGIN_PX = 8  # a sole closer than this to the edge of what both cameras see is cut off
SOLE_MASK_ERODE_PX = 1  # sub-pixel fits keep this far from the edge: its pixels mix sole and table
# On images soft at the sole's edge (cellctl.vision.edge_blur) the mixed band is wider: the fits keep 3 px away.
# Not on sharp ones: there the glue path's patches (2 mm from the edge) lost the pixels that average their noise,
# and their expected errors rose by a third (set 32000: 17 of 44 soles refused for it, none made more right).
SOFT_SOLE_MASK_ERODE_PX = 3
WALL_FOOT_MM = 1.0  # ~5 sigma of the table's height noise: lower changed points are table (a shadow)
EDGE_BAND_MM = 6.0  # low points this close to the raised footprint may be sole (a leaning wall's foot)
UNMEASURED_CLOSE_PX = 61  # ~24 mm: closes the sole's image region over patches of glare
# The change masks are computed this far round the sole's high points (~40 mm: past fattening, a leaning
# wall's foot, the outline checks' 7 mm and the unmeasured-pixel closing's 24 mm).
CHANGE_MARGIN_PX = 100
SHADOW_BANDS = True  # cellctl.vision.shadow_band
# A pixel is on the raised sole for the change test (`ChangeTest.changed(raised=...)`) where no point measured
# at the table's level (within WALL_FOOT_MM) lies within this many pixels (~2 mm). The matcher drags the
# sole's disparity onto the table beside its edge by up to about its census window's half width (4 px): a
# shadow band there still has table-level readings within this reach, the sole's inside has none.
TABLE_DEPTH_REACH_PX = 5
MIN_SOLE_AREA_MM2 = 5000.0  # smaller regions are not a sole (the smallest soles are ~ 15000 mm^2)
MIN_COLOUR_SEPARATION = 4.0  # sole and table colours this many standard deviations apart: filter by colour


@dataclass(frozen=True)
class ColourSplit:
    """The colour discriminant's verdict on the high points."""

    sole: np.ndarray  # bool per high point: sole-coloured (all True when the filter is not applied)
    applied: bool  # whether the colours separated enough to filter
    separation: float  # sole/table colour distance in standard deviations


@dataclass(frozen=True)
class ChangeSplit:
    """The change test's verdict against the taught table."""

    sole: np.ndarray  # indices of the sole's points, sorted
    changed_left: np.ndarray  # bool, rectified left pixels changed against the taught table
    changed_right: np.ndarray | None  # the same for the right image (None: its table not seen)
    test: ChangeTest  # the left image's against its taught reference
    # Points above the table on a cast shadow's band (cellctl.vision.shadow_band): depth carried over the band.
    shadowed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def table_sample(points: np.ndarray) -> np.ndarray:
    """Every 4th table point (indices; ~150000): the table's colour and change statistics are as exact from
    them, at a quarter the time."""
    return np.flatnonzero(np.abs(points[:, 2]) < TABLE_INLIER_MM)[::4]


def colour_split(colours: np.ndarray, points: np.ndarray, footprint: Footprint, high: np.ndarray) -> ColourSplit:
    """Which of the `high` points (indices) are sole-coloured (all when the colours do not separate).

    Linear discriminant between the table's colour (plane inliers outside the sole) and the sole's
    (points well inside the footprint), thresholded half way between the two means, which is where a
    pixel half covered by the sole lies: the edge stays where it is.
    """
    everything = np.ones(len(high), bool)
    table = table_sample(points)
    # Rows are gathered with np.take (the same rows as indexing; ~3 x faster on ~10^5 rows); the raster kernels
    # read the x y of x y z rows in place.
    interior = high[footprint.eroded(5.0).contains(np.take(points, high, axis=0))]
    outside = table[~footprint.dilated(10.0).contains(np.take(points, table, axis=0))]
    if interior.size < 100 or outside.size < 100:
        return ColourSplit(everything, False, 0.0)
    sole_c = np.take(colours, interior, axis=0).astype(np.float64)
    table_c = np.take(colours, outside, axis=0).astype(np.float64)
    pooled = 0.5 * (np.cov(sole_c.T) + np.cov(table_c.T)) + np.eye(3) * 1e-3
    sole_mean, table_mean = sole_c.mean(axis=0), table_c.mean(axis=0)  # each taken once (~10^5 rows)
    difference = sole_mean - table_mean
    direction = np.linalg.solve(pooled, difference)
    separation = float(np.sqrt(direction @ difference))
    if separation < MIN_COLOUR_SEPARATION:
        return ColourSplit(everything, False, separation)
    threshold = direction @ (0.5 * (sole_mean + table_mean))
    return ColourSplit(np.take(colours, high, axis=0).astype(np.float64) @ direction > threshold, True, separation)


def change_split(
    cloud: StereoCloud,
    taught: TaughtTable,
    points: np.ndarray,
    footprint: Footprint,
    high: np.ndarray,
    min_height_mm: float,
) -> ChangeSplit | None:
    """The sole's points (indices): changed against the taught table (cellctl.vision.change), and either
    high or within EDGE_BAND_MM of the raised footprint; None if the table around is not seen.

    Stereo edge fattening drags the sole's height onto table pixels next to it, but those pixels still
    show the table's own texture: unchanged, so dropped. The foot of a wall that leans out lies lower
    than MIN_HEIGHT_MM but has changed: kept, so the outline is the footprint on the table.
    """
    assert cloud.rectified is not None  # a taught table is only used on a stereo cloud
    current, reference = cloud.rectified[0], taught.left
    table = table_sample(points)
    outside = table[~footprint.dilated(15.0).contains(np.take(points, table, axis=0))]
    outside_pixels = np.take(cloud.pixels, outside, axis=0)
    test = ChangeTest.fit(current, reference, np.round(outside_pixels).astype(np.int64))
    if test is None:
        return None
    # The masks are read near the sole only (its points, the outline's checks, the image edge): computed in
    # the box of the high points and CHANGE_MARGIN_PX round it, the rest of the image is left unchanged.
    left_box, right_box = _change_boxes(cloud, high, current.shape)
    raised_left, raised_right = _raised(cloud, points, current.shape)
    lifted_left, lifted_right = _lifted(cloud, high, (raised_left, raised_right))
    changed = test.changed(current, reference, left_box, raised_left, lifted_left)
    # The right image against its own reference, for the outline's left/right check (cellctl.vision.checks).
    right_table = outside_pixels - np.column_stack([cloud.disparity[outside], np.zeros(len(outside))])
    right_test = ChangeTest.fit(cloud.rectified[1], taught.right, np.round(right_table).astype(np.int64))
    changed_right = (
        None
        if right_test is None
        else right_test.changed(cloud.rectified[1], taught.right, right_box, raised_right, lifted_right)
    )
    band_left = None
    if SHADOW_BANDS and changed_right is not None and right_test is not None and cloud.calibration is not None:
        band_left, band_right = _shadow_bands(cloud, taught, points, (changed, changed_right), (test, right_test))
        changed, changed_right = changed & ~band_left, changed_right & ~band_right
    # The foot of a leaning wall, not the table: a cast shadow changes the image but lies at z ~ 0.
    near = np.flatnonzero((points[:, 2] > WALL_FOOT_MM) & (points[:, 2] <= min_height_mm))
    near = near[footprint.dilated(EDGE_BAND_MM).contains(np.take(points, near, axis=0))]
    candidates = np.concatenate([high, near])
    x, y = np.round(np.take(cloud.pixels, candidates, axis=0)).astype(np.int64).T
    # Sorted as np.sort would give them (high and near are disjoint): marked on the points, read back in order
    # (one pass over the points instead of a sort of the ~2 10^5 chosen).
    chosen = np.zeros(len(points), bool)
    chosen[candidates[changed[y, x]]] = True
    # The high points on the left band (the first of the candidates): depth carried over it.
    shadowed = high[band_left[y[: len(high)], x[: len(high)]]] if band_left is not None else np.zeros(0, np.int64)
    return ChangeSplit(np.flatnonzero(chosen), changed, changed_right, test, shadowed)


def _shadow_bands(
    cloud: StereoCloud,
    taught: TaughtTable,
    points: np.ndarray,
    changed: tuple[np.ndarray, np.ndarray],
    tests: tuple[ChangeTest, ChangeTest],
) -> tuple[np.ndarray, np.ndarray]:
    """A cast shadow's band beside the sole in the left and the right change mask (cellctl.vision.shadow_band)."""
    assert cloud.rectified is not None and cloud.calibration is not None
    left, right = cloud.rectified
    table = TableDisparity.of(taught.plane, cloud.calibration)
    pixel_mm = taught.plane.pixel_mm(cloud.calibration)
    # How much wider than the table's the sole's disparity runs: the strip beside its edge one camera sees and the
    # other does not (shadow_band grows a band found over it).
    above = np.flatnonzero(points[:, 2] > WALL_FOOT_MM)
    hidden_px = 0.0
    if above.size:
        table_disparity = table.at(cloud.pixels[above, 0], cloud.pixels[above, 1])
        hidden_px = float(np.percentile(cloud.disparity[above] - table_disparity, 99))
    # The right image's on the second core (numpy and OpenCV release the GIL): ~9 ms each.
    right_band = worker("shadow-band").submit(
        shadow_band,
        changed[1],
        right,
        left,
        table,
        True,
        tests[1],
        taught.right,
        tests[0].sigma,
        pixel_mm,
        _heights(cloud, points, True),
        hidden_px,
    )
    try:
        band_left = shadow_band(
            changed[0],
            left,
            right,
            table,
            False,
            tests[0],
            taught.left,
            tests[1].sigma,
            pixel_mm,
            _heights(cloud, points, False),
            hidden_px,
        )
    finally:
        band_right = right_band.result()
    return band_left, band_right


def _heights(cloud: StereoCloud, points: np.ndarray, right: bool) -> Callable[[tuple[slice, slice]], np.ndarray]:
    """For a box of the left (or right) rectified image, the heights of the points measured there above the table's
    level (WALL_FOOT_MM; the right image's at x - disparity), NaN where none was: read only where a band is found."""

    def within(box: tuple[slice, slice]) -> np.ndarray:
        above = np.flatnonzero(points[:, 2] > WALL_FOOT_MM)
        x = cloud.pixels[above, 0] - (cloud.disparity[above] if right else 0.0)
        rows = np.round(cloud.pixels[above, 1]).astype(np.int64) - box[0].start
        columns = np.round(x).astype(np.int64) - box[1].start
        image = np.full((box[0].stop - box[0].start, box[1].stop - box[1].start), np.nan, np.float32)
        inside = (rows >= 0) & (rows < image.shape[0]) & (columns >= 0) & (columns < image.shape[1])
        image[rows[inside], columns[inside]] = points[above[inside], 2]
        return image

    return within


def _raised(cloud: StereoCloud, points: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Left and right rectified pixels with no point measured at the table's level within
    TABLE_DEPTH_REACH_PX (the right ones at x - disparity)."""
    level = np.flatnonzero(np.abs(points[:, 2]) < WALL_FOOT_MM)
    reach = np.ones((2 * TABLE_DEPTH_REACH_PX + 1,) * 2, np.uint8)
    left, right = (cv2.dilate(seen, reach) == 0 for seen in _marked(cloud, level, shape))
    return left, right


def _lifted(
    cloud: StereoCloud, high: np.ndarray, raised: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Left and right rectified pixels depth puts on the sole (`ChangeTest.changed(lifted=...)`): raised (no
    table-level point within reach) and a high point (`high`, indices) on the pixel or next to it (the right
    ones at x - disparity); the neighbours close the gaps between the points' rounded pixels."""
    near = np.ones((3, 3), np.uint8)
    left, right = (
        (cv2.dilate(on, near) > 0) & raised_pixels
        for on, raised_pixels in zip(_marked(cloud, high, raised[0].shape), raised, strict=True)
    )
    return left, right


def _marked(cloud: StereoCloud, index: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The left and right rectified images (uint8) with 1 at the pixels of the points `index` (the right ones
    at x - disparity), 0 elsewhere; points off an image are left out of it."""
    # In C (cellctl.stereo.kernels.mark_pixels): one pass over the ~3 10^5 points instead of numpy's ~15 (gather,
    # round, bounds and scatter per image), the same pixels (np.round's halves to even).
    left, right = mark_pixels(cloud.pixels, cloud.disparity, index, (shape[0], shape[1]))
    assert right is not None  # given the disparities
    return left, right


def _change_boxes(
    cloud: StereoCloud, high: np.ndarray, shape: tuple[int, ...]
) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """(rows, columns) of the left and right images round the high points, CHANGE_MARGIN_PX out (the right
    one shifted by their disparities)."""
    x, y = np.take(cloud.pixels, high, axis=0).T
    return pixel_boxes(x, y, cloud.disparity[high], CHANGE_MARGIN_PX, shape)


def pixel_boxes(
    x: np.ndarray, y: np.ndarray, disparity: np.ndarray, margin: int, shape: tuple[int, ...]
) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """(rows, columns) of the left and right rectified images round left pixels (x, y) (at least one), `margin`
    out and within the images; the right one round x - disparity."""
    height, width = shape[:2]
    rows = slice(max(int(y.min()) - margin, 0), min(int(y.max()) + margin + 1, height))
    left = slice(max(int(x.min()) - margin, 0), min(int(x.max()) + margin + 1, width))
    right_x = x - disparity
    right = slice(max(int(right_x.min()) - margin, 0), min(int(right_x.max()) + margin + 1, width))
    return (rows, left), (rows, right)


def why_no_sole(
    cloud: StereoCloud, taught: TaughtTable | None, plane: TablePlane | None, points: np.ndarray, reason: str
) -> tuple[FailureKind, str]:
    """NO_SOLE with `reason`, unless the taught table shows a sole-sized change that depth did not measure.

    Heavy sensor noise or glare on a dark sole can leave too few matched points to raise a sole-sized
    footprint: the sole is there, and "no sole in view" would send the operator looking for nothing.
    """
    area = 0.0 if taught is None or plane is None else changed_area_mm2(cloud, taught, plane, points)
    if area < MIN_SOLE_AREA_MM2:
        return FailureKind.NO_SOLE, reason
    return FailureKind.TOO_FEW_POINTS, (
        f"something sole-sized lies on the table ({area:.0f} mm^2 changed against the taught table) but too "
        "little of it was measured in depth (sensor noise, glare or no texture): check lighting and exposure"
    )


def changed_area_mm2(cloud: StereoCloud, taught: TaughtTable, plane: TablePlane, points: np.ndarray) -> float:
    """Area of the largest region changed against the taught table (0 when the table cannot be compared)."""
    if cloud.rectified is None:
        return 0.0
    table = table_sample(points)
    current = cloud.rectified[0]
    test = ChangeTest.fit(current, taught.left, np.round(cloud.pixels[table]).astype(np.int64))
    if test is None:
        return 0.0
    changed = test.changed(current, taught.left).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(changed, connectivity=8)
    largest = int(stats[1:, cv2.CC_STAT_AREA].max()) if count > 1 else 0
    pixel_mm = plane.pixel_mm(cloud.calibration) if cloud.calibration else 0.0
    return largest * pixel_mm**2


def depth_step(raster: Footprint, every: np.ndarray, high_counts: np.ndarray) -> tuple[Footprint, Footprint]:
    """The depth step on the footprint's raster, for the outline's self-check (cellctl.vision.checks): the
    cells where most measured points rise above the table, and the cells with any measured point."""
    # The raster is finer than the pixels: cells between measured ones are filled from their neighbours.
    raised = Footprint(
        ((high_counts > 0) & (2 * high_counts >= every)).astype(np.uint8), raster.origin, raster.cell_mm
    ).morphology(close_mm=1.5, open_mm=0.0)
    measured_cells = Footprint((every > 0).astype(np.uint8), raster.origin, raster.cell_mm).dilated(0.75)
    return raised, measured_cells


@dataclass(frozen=True)
class PointSpread:
    """Per point of a set (`point_spread`): its mean distance to its 20 nearest among them (mm), and whether that
    makes it an isolated speck of depth (outliers.ISOLATED_SPACINGS)."""

    distance: np.ndarray
    isolated: np.ndarray


def point_spread(cloud: StereoCloud, index: np.ndarray, points: np.ndarray) -> PointSpread | None:
    """The spread of the points `index` of a stereo cloud; None for another cloud (no pixel grid to find the
    neighbours on, e.g. a true depth map)."""
    calib = cloud.calibration
    if calib is None:
        return None
    spacing = calib.baseline_mm / cloud.disparity[index]  # between pixels at the point: Z / f = B / d
    distance = mean_neighbour_distances(np.take(cloud.pixels, index, axis=0), np.take(points, index, axis=0), spacing)
    return PointSpread(distance, distance > ISOLATED_SPACINGS * spacing)


def without_outliers(
    cloud: StereoCloud, index: np.ndarray, points: np.ndarray, distance: np.ndarray | None = None
) -> np.ndarray:
    """The points (indices) that statistical outlier removal keeps; `distance`: their mean neighbour distances
    (`point_spread`) where already known."""
    if distance is None:
        spread = point_spread(cloud, index, points)
        if spread is None:  # not a stereo cloud, so not one point per rectified pixel (e.g. a true depth map)
            o3d_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[index]))
            _, inliers = o3d_cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
            return index[np.asarray(inliers, dtype=np.int64)]
        distance = spread.distance
    return index[inliers_by_mean(distance)]


def sole_mask(cloud: StereoCloud, index: np.ndarray) -> tuple[np.ndarray | None, bool]:
    """Rectified left pixels on the sole (measured ones, small holes closed, the edge's mixed pixels dropped), and
    whether the images are soft at its edge (`edge_blur.soft_edges`: more pixels dropped)."""
    if cloud.rectified is None:
        return None, False
    width, height = cloud.image_size
    mask, _ = mark_pixels(cloud.pixels, None, index, (height, width))  # in C: one pass over the points
    closed = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    soft = index.size > 0 and soft_edges(*cloud.rectified, closed > 0, float(np.median(cloud.disparity[index])))
    erode = SOFT_SOLE_MASK_ERODE_PX if soft else SOLE_MASK_ERODE_PX
    return cv2.erode(closed, np.ones((erode * 2 + 1,) * 2, np.uint8)) > 0, soft


def unmeasured_fraction(cloud: StereoCloud, changed_left: np.ndarray | None, index: np.ndarray) -> float:
    """Share of the sole's changed pixels (taught table only) without a measured point: glare, no texture.

    The sole's image region is its measured pixels closed over UNMEASURED_CLOSE_PX, and every changed region
    those pixels touch: a glossy toe whose whole tip lost its depth is changed but lies beyond any closing
    of the measured pixels. Where that region holds many changed pixels without depth, an outline that
    disagrees with the depth step has lost part of the sole to unmeasured pixels, and that is the reason to
    give (cellctl.vision.measurement).
    """
    if changed_left is None or index.size == 0:
        return 0.0
    width, height = cloud.image_size
    # The sole's measured pixels and every measured pixel, marked on the left image (in C, one pass each).
    sole_pixels, _ = mark_pixels(cloud.pixels, None, index, (height, width))
    measured_pixels, _ = mark_pixels(cloud.pixels, None, None, (height, width))
    sole_rows, sole_columns = np.flatnonzero(np.any(sole_pixels, axis=1)), np.flatnonzero(np.any(sole_pixels, axis=0))
    # The changed regions the sole's measured pixels lie in (8-connected), as a mask and their box; labelled
    # within the box of the changed pixels only (the change masks are computed round the sole).
    changed_rows = np.flatnonzero(np.any(changed_left, axis=1))
    changed_columns = np.flatnonzero(np.any(changed_left, axis=0))
    changed_sole = np.zeros(changed_left.shape, bool)
    if changed_rows.size:
        box = (slice(changed_rows[0], changed_rows[-1] + 1), slice(changed_columns[0], changed_columns[-1] + 1))
        count, labels = cv2.connectedComponents(changed_left[box].view(np.uint8), connectivity=8)
        touched = np.zeros(count, bool)
        touched[labels[sole_pixels[box].view(bool)]] = True
        touched[0] = False  # the unchanged background
        changed_sole[box] = touched[labels]
    rows, columns = np.flatnonzero(np.any(changed_sole, axis=1)), np.flatnonzero(np.any(changed_sole, axis=0))
    # Only the box of the sole and its changed regions and a margin of twice the disc's reach: outside it the
    # whole image's closing is empty, and inside it the same (a cell within the disc's reach of the box's
    # edge is farther than the reach from the sole, so unmarked after the dilation, and the erosion keeps it
    # unmarked).
    margin = UNMEASURED_CLOSE_PX + 1
    top = max(min(int(sole_rows[0]), int(rows[0]) if rows.size else height) - margin, 0)
    left = max(min(int(sole_columns[0]), int(columns[0]) if columns.size else width) - margin, 0)
    bottom = min(max(int(sole_rows[-1]), int(rows[-1]) if rows.size else 0) + margin + 1, height)
    right = min(max(int(sole_columns[-1]), int(columns[-1]) if columns.size else 0) + margin + 1, width)
    within = (slice(top, bottom), slice(left, right))
    region = disc_closing(np.ascontiguousarray(sole_pixels[within]), UNMEASURED_CLOSE_PX) > 0
    region |= changed_sole[within]
    lost = region & changed_left[within] & ~measured_pixels[within].view(bool)
    return float(np.count_nonzero(lost)) / max(float(np.count_nonzero(region)), 1.0)


def disc_closing(mask: np.ndarray, size: int) -> np.ndarray:
    """cv2.morphologyEx(mask, MORPH_CLOSE, the size x size MORPH_ELLIPSE element) of a 0/1 uint8 mask: the
    same cells, in C (cellctl.stereo.kernels.disc_dilate), ~3 x faster than as the union of its rectangles.

    OpenCV's disc is a stack of centred runs, widest in the middle row. A cell is in the dilation where some
    row of the disc finds a marked cell within its run along that row; the erosion is the dilation of the
    unmarked cells, complemented (cells off the raster count as unmarked for the dilation and as marked for the
    erosion, OpenCV's default border)."""
    half_widths = _disc_runs(size)
    return disc_dilate(disc_dilate(mask, half_widths), half_widths, of_zero=True, invert=True)


def _disc_runs(size: int) -> np.ndarray:
    """Half widths of the centred runs, row by row, of OpenCV's size x size elliptic element (odd size)."""
    if size < 1 or size % 2 == 0:
        raise ValueError(f"the disc must have an odd size, got {size}")
    disc, middle = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)), size // 2
    half_widths = []
    for row in disc:
        columns = np.flatnonzero(row)
        half = middle - int(columns[0])
        assert int(columns[-1]) == middle + half and len(columns) == 2 * half + 1  # a centred run
        half_widths.append(half)
    return np.array(half_widths, np.int32)


def cut_by_border(cloud: StereoCloud, index: np.ndarray) -> tuple[FailureKind | None, str | None]:
    """Failure kind and reason if the sole reaches the edge of what both cameras see (else None, None)."""
    if index.size == 0:
        return FailureKind.NO_SOLE, "no sole in view: no sole points left after outlier removal"
    width, height = cloud.image_size
    x, y = np.take(cloud.pixels, index, axis=0).T
    d = cloud.disparity[index]
    m = BORDER_MARGIN_PX
    # x - d < m: the right camera does not see the point (it left the right image on the left).
    at_edge = (x < m) | (x > width - 1 - m) | (y < m) | (y > height - 1 - m) | (x - d < m)
    if np.any(at_edge):
        return FailureKind.SOLE_AT_BORDER, (
            "sole cut by the image border: move the sole towards the middle of the table "
            f"({int(at_edge.sum())} sole points within {m} px of the edge of the common view)"
        )
    return None, None
