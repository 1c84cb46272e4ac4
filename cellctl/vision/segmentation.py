"""Background removal: from the measured cloud to the sole's points in the table frame, or the reason there
are none (docs/measurements.md).

1. find the table plane (RANSAC, refined on the images) or use a plane stored at set-up, and move
   everything into the table frame;
2. points at least `min_height_mm` above the table and sole-coloured (the paper's colour filter, with the
   threshold learnt from the scene). The colour filter also removes the halo of table pixels that
   window-based matching drags onto the sole's disparity at its edge (edge fattening, 1-5 mm on simulated
   soles); a sole whose colour does not separate from the table's is therefore not measured (invalid, with
   the reason) rather than measured too long;
3. the sole is the largest connected region of the footprint raster (cellctl.vision.footprint), holes filled;
4. statistical outlier removal (cellctl.vision.outliers) on the sole's points, and a mask of the sole's
   pixels so that heights can be refined on the images (cellctl.vision.surface, cellctl.vision.subpixel).

Over 350 lines (~430): the result types and one run's steps, which share its state (Segmentation, a class
over 150 lines for that reason); the issue 11 rework of these steps is under way, the split after it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import open3d as o3d

from cellctl.errors import FailureKind
from cellctl.vision.calibration import Calibration
from cellctl.vision.change import ChangeTest
from cellctl.vision.cloud import StereoCloud
from cellctl.vision.footprint import Footprint
from cellctl.vision.outliers import statistical_inliers
from cellctl.vision.table import TABLE_INLIER_MM, TablePlane, find_table, refine_table
from cellctl.vision.teach import TaughtTable, check_drift

MIN_HEIGHT_MM = 3.0  # points lower than this belong to the table (its height noise is well below 1 mm)
MAX_HEIGHT_MM = 150.0  # anything higher is not a sole lying on the table (a hand, the robot)
MIN_VALID_FRACTION = 0.15  # fewer measured pixels than this: the pair cannot be trusted
MIN_SOLE_AREA_MM2 = 5000.0  # smaller regions are not a sole (the smallest soles are ~ 15000 mm^2)
BORDER_MARGIN_PX = 8  # a sole closer than this to the edge of what both cameras see is cut off
FOOTPRINT_CELL_MM = 0.25  # below the pixel spacing (0.39 mm): the outline is not quantised to a coarse grid
SOLE_MASK_ERODE_PX = 1  # sub-pixel fits keep this far from the edge: its pixels mix sole and table
FOOTPRINT_OPEN_MM = 1.0  # specks thinner than this go; a pointed toe's tip (radius >= 0.5 mm) stays
COLOUR_OPEN_MM = 2.0  # the same without a taught table: the colour edge's noise needs the wider opening
WALL_FOOT_MM = 1.0  # ~5 sigma of the table's height noise: lower changed points are table (a shadow)
EDGE_BAND_MM = 6.0
UNMEASURED_CLOSE_PX = 61  # ~24 mm: closes the sole's image region over patches of glare  # low points this close to the raised footprint may be sole (a leaning wall's foot)
MIN_COLOUR_SEPARATION = 4.0  # sole and table colours this many standard deviations apart: filter by colour


class _SolePoints:
    """The sole's points as an Open3D cloud (both result types carry the points found, possibly none)."""

    sole_points: np.ndarray
    sole_colors: np.ndarray

    def point_cloud(self) -> o3d.geometry.PointCloud:
        """The sole as an Open3D cloud with RGB colours (for PLY output and viewing)."""
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(self.sole_points, np.float64)))
        # Contiguous float64: Open3D copies that in one go, anything else element by element (~50 ms per cycle).
        rgb = np.ascontiguousarray(np.clip(self.sole_colors[:, ::-1] / 255.0, 0.0, 1.0), np.float64)
        cloud.colors = o3d.utility.Vector3dVector(rgb)
        return cloud


@dataclass
class Reconstruction(_SolePoints):
    """A sole found: its points in the table frame (the success of `ReconstructionResult`)."""

    sole_points: np.ndarray  # N x 3, table frame, mm
    sole_colors: np.ndarray  # N x 3 BGR 0..255
    sole_pixels: np.ndarray  # N x 2 (x, y) in the rectified left image
    footprint: Footprint
    camera_to_table: np.ndarray  # 4 x 4, rectified left camera -> table
    table_plane: TablePlane
    colour_filter: bool  # whether the colour filter was applied
    colour_separation: float  # sole/table colour distance in standard deviations
    measured_points: int
    measured_fraction: float
    timings: dict[str, float] = field(default_factory=dict)
    calibration: Calibration | None = None  # None: not a stereo cloud (e.g. a true depth map)
    rectified: tuple[np.ndarray, np.ndarray] | None = None  # grey float32 rectified pair
    sole_mask: np.ndarray | None = None  # bool, rectified left pixels on the sole (off its very edge)
    # The depth step on the footprint's raster, for the outline's self-check (cellctl.vision.checks):
    raised: Footprint | None = None  # cells where most measured points rise above the table
    measured_cells: Footprint | None = None  # cells with any measured point
    taught: TaughtTable | None = None  # the taught table the sole was found against, if any
    changed_right: np.ndarray | None = None  # bool, rectified right pixels changed against the taught table
    unmeasured_fraction: float = 0.0  # of the sole's changed pixels without depth (glare, no texture)

    @property
    def valid(self) -> bool:
        return True


@dataclass
class ReconstructionRefused(_SolePoints):
    """No sole to measure: why (kind for programs, reason for people) and what was learnt on the way there."""

    failure: FailureKind
    reason: str
    measured_points: int
    measured_fraction: float
    table_plane: TablePlane | None = None
    camera_to_table: np.ndarray | None = None  # 4 x 4, rectified left camera -> table, once the plane is known
    colour_filter: bool = False
    colour_separation: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    # The sole's points when it was found but refused (e.g. cut by the border), for pictures; else none.
    sole_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sole_colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    footprint: Footprint | None = None

    @property
    def valid(self) -> bool:
        return False


ReconstructionResult = Reconstruction | ReconstructionRefused


class Segmentation:
    """One run of the segmentation; a class only to keep the steps short and their shared state named."""

    def __init__(
        self,
        cloud: StereoCloud,
        table_plane: TablePlane | None,
        min_height_mm: float,
        taught: TaughtTable | None = None,
    ) -> None:
        self.cloud = cloud
        self.taught = taught
        self.plane = table_plane
        self.min_height = min_height_mm
        self.timings = dict(cloud.timings)
        self.measured = len(cloud.points)
        self.fraction = self.measured / float(cloud.matched_area)  # of the pixels matched (a search region)
        self.transform: np.ndarray | None = None
        self.colour_filter = False
        self.separation = 0.0
        self.raised: Footprint | None = None  # cells where most measured points rise above the table
        self.measured_cells: Footprint | None = None  # cells with any measured point
        self.changed_right: np.ndarray | None = None
        self._changed_left: np.ndarray | None = None

    def run(self) -> ReconstructionResult:
        if self.fraction < MIN_VALID_FRACTION:
            return self._fail(
                FailureKind.TOO_FEW_POINTS,
                f"too few measured points: {self.measured} ({100 * self.fraction:.1f} % of the image, need "
                f"{100 * MIN_VALID_FRACTION:.0f} %); check lighting, focus, the calibration and the depth range",
            )
        start = time.perf_counter()
        if self.plane is None:
            self.plane = find_table(self.cloud.points)
            if self.plane is not None and self.cloud.rectified is not None:
                self.plane = refine_table(self.cloud, self.plane)
        self.timings["table_plane"] = time.perf_counter() - start
        if self.plane is None:
            return self._fail(
                FailureKind.NO_TABLE, "no table plane found: the table must fill most of the view, below the sole"
            )
        if self.taught is not None:
            drift = check_drift(self.taught, self.cloud.points)
            self.timings["table_drift"] = time.perf_counter() - start
            if drift.problem is not None:
                return self._fail(FailureKind.TABLE_MOVED, drift.problem)
        transform = self.plane.camera_to_table()
        points = self.cloud.points @ transform[:3, :3].T + transform[:3, 3]
        # The table frame's z is the height above the plane: no second pass over the ~10^6 points for it.
        below = float(np.mean(points[:, 2] < -5.0 * TABLE_INLIER_MM))
        if below > 0.05:
            return self._fail(
                FailureKind.NO_TABLE,
                f"{100 * below:.0f} % of the points lie below the table plane: the plane found is not the table",
            )
        self.transform = transform
        return self._sole(points)

    def _sole(self, points: np.ndarray) -> ReconstructionResult:
        start = time.perf_counter()
        xy, z = points[:, :2], points[:, 2]
        # Indices rather than masks: most points are table, and only the high ones can be sole.
        high = np.flatnonzero((z > self.min_height) & (z < MAX_HEIGHT_MM))
        no_sole = f"no sole in view: nothing larger than {MIN_SOLE_AREA_MM2:.0f} mm^2 above the table"
        if high.size == 0:
            return self._no_sole(points, no_sole)
        # One raster for both footprints, over the high points only (cells elsewhere cannot be sole); its
        # cells lie on the same lattice whatever it covers (Footprint.empty_like).
        raster = Footprint.empty_like(xy[high], FOOTPRINT_CELL_MM)
        every = raster.counts(xy)  # all measured points per cell: "most of a cell's points" needs them
        footprint = _footprint(raster, every, xy[high])
        if footprint.area_mm2 < MIN_SOLE_AREA_MM2:
            return self._no_sole(points, no_sole)
        high_counts = raster.counts(xy[high])
        # The raster is finer than the pixels: cells between measured ones are filled from their neighbours.
        self.raised = Footprint(
            ((high_counts > 0) & (2 * high_counts >= every)).astype(np.uint8), raster.origin, raster.cell_mm
        ).morphology(close_mm=1.5, open_mm=0.0)
        self.measured_cells = Footprint((every > 0).astype(np.uint8), raster.origin, raster.cell_mm).dilated(0.75)
        if self.taught is not None:
            changed = self._change_filter(points, footprint, high)
            if changed is None:
                return self._fail(
                    FailureKind.TABLE_MOVED,
                    "too little of the taught table is visible around the sole to compare with: clear the table",
                )
            keep = changed
        else:
            keep = high[self._colour_filter(points, footprint, high)]
        if self.taught is None and not self.colour_filter:
            # Without the colour edge, matching halos widen the sole by 1-5 mm (simulated soles): no length.
            return self._fail(
                FailureKind.COLOURS_TOO_SIMILAR,
                f"sole and table colours too similar to find the sole's edge (they differ by "
                f"{self.separation:.1f} standard deviations, need {MIN_COLOUR_SEPARATION:g}): use a table "
                "surface that contrasts with the sole",
            )
        # The colour edge is noisier than the change edge (a black sole's colour noise): it keeps the coarser
        # opening it was tuned with; the change edge keeps a pointed toe's tip.
        footprint = _footprint(raster, every, xy[keep], FOOTPRINT_OPEN_MM if self.taught else COLOUR_OPEN_MM)
        if footprint.area_mm2 < MIN_SOLE_AREA_MM2:
            return self._fail(FailureKind.NO_SOLE, "no sole in view: the region above the table has the table's colour")
        index = keep[footprint.contains(xy[keep]) & (z[keep] > self.min_height)]  # the foot of a wall: outline only
        self.timings["background"] = time.perf_counter() - start
        start = time.perf_counter()
        index = self._without_outliers(index, points)
        self.timings["outliers"] = time.perf_counter() - start
        failure, reason = self._cut_by_border(index)
        return self._result(
            failure,
            reason,
            sole_points=points[index],
            sole_colors=self.cloud.colors[index],
            sole_pixels=self.cloud.pixels[index],
            footprint=footprint,
            rectified=self.cloud.rectified,
            sole_mask=self._sole_mask(index),
            unmeasured_fraction=self._unmeasured_fraction(index),
        )

    def _without_outliers(self, index: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The points (indices) that statistical outlier removal keeps."""
        calib = self.cloud.calibration
        if calib is None:  # not a stereo cloud, so not one point per rectified pixel (e.g. a true depth map)
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[index]))
            _, inliers = cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
            return index[np.asarray(inliers, dtype=np.int64)]
        spacing = calib.baseline_mm / self.cloud.disparity[index]  # between pixels at the point: Z / f = B / d
        return index[statistical_inliers(self.cloud.pixels[index], points[index], spacing)]

    def _sole_mask(self, index: np.ndarray) -> np.ndarray | None:
        """Rectified left pixels on the sole: measured ones, small holes closed, the edge pixel dropped."""
        if self.cloud.rectified is None:
            return None
        width, height = self.cloud.image_size
        mask = np.zeros((height, width), np.uint8)
        x, y = np.round(self.cloud.pixels[index]).astype(int).T
        mask[y, x] = 1
        closed = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
        return cv2.erode(closed, np.ones((SOLE_MASK_ERODE_PX * 2 + 1,) * 2, np.uint8)) > 0

    def _no_sole(self, points: np.ndarray, reason: str) -> ReconstructionResult:
        """NO_SOLE, unless the taught table shows a sole-sized change that depth did not measure.

        Heavy sensor noise or glare on a dark sole can leave too few matched points to raise a sole-sized
        footprint: the sole is there, and "no sole in view" would send the operator looking for nothing.
        """
        if self.taught is None or self.cloud.rectified is None or self.plane is None:
            return self._fail(FailureKind.NO_SOLE, reason)
        table = np.flatnonzero(np.abs(points[:, 2]) < TABLE_INLIER_MM)[::4]
        current = self.cloud.rectified[0]
        test = ChangeTest.fit(current, self.taught.left, np.round(self.cloud.pixels[table]).astype(np.int64))
        if test is None:
            return self._fail(FailureKind.NO_SOLE, reason)
        changed = test.changed(current, self.taught.left).astype(np.uint8)
        count, _, stats, _ = cv2.connectedComponentsWithStats(changed, connectivity=8)
        largest = int(stats[1:, cv2.CC_STAT_AREA].max()) if count > 1 else 0
        pixel_mm = self.plane.offset / self.cloud.calibration.focal_px if self.cloud.calibration else 0.0
        area = largest * pixel_mm**2
        if area < MIN_SOLE_AREA_MM2:
            return self._fail(FailureKind.NO_SOLE, reason)
        return self._fail(
            FailureKind.TOO_FEW_POINTS,
            f"something sole-sized lies on the table ({area:.0f} mm^2 changed against the taught table) but too "
            "little of it was measured in depth (sensor noise, glare or no texture): check lighting and exposure",
        )

    def _unmeasured_fraction(self, index: np.ndarray) -> float:
        """Share of the sole's changed pixels (taught table only) without a measured point: glare, no texture.

        The sole's image region is its measured pixels closed over UNMEASURED_CLOSE_PX; where that holds
        many changed pixels without depth, an outline that disagrees with the depth step has lost part of
        the sole to unmeasured pixels, and that is the reason to give (cellctl.vision.measurement).
        """
        if self._changed_left is None or index.size == 0:
            return 0.0
        width, height = self.cloud.image_size
        sole = np.zeros((height, width), np.uint8)
        x, y = np.round(self.cloud.pixels[index]).astype(int).T
        sole[y, x] = 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (UNMEASURED_CLOSE_PX, UNMEASURED_CLOSE_PX))
        region = cv2.morphologyEx(sole, cv2.MORPH_CLOSE, kernel) > 0
        measured = np.zeros((height, width), bool)
        mx, my = np.round(self.cloud.pixels).astype(int).T
        measured[my, mx] = True
        lost = region & self._changed_left & ~measured
        return float(np.count_nonzero(lost)) / max(float(np.count_nonzero(region)), 1.0)

    def _change_filter(self, points: np.ndarray, footprint: Footprint, high: np.ndarray) -> np.ndarray | None:
        """The sole's points (indices): changed against the taught table (cellctl.vision.change), and either
        high or within EDGE_BAND_MM of the raised footprint; None if the table around is not seen.

        Stereo edge fattening drags the sole's height onto table pixels next to it, but those pixels still
        show the table's own texture: unchanged, so dropped. The foot of a wall that leans out lies lower
        than MIN_HEIGHT_MM but has changed: kept, so the outline is the footprint on the table.
        """
        assert self.taught is not None and self.cloud.rectified is not None
        current, reference = self.cloud.rectified[0], self.taught.left
        table = np.flatnonzero(np.abs(points[:, 2]) < TABLE_INLIER_MM)[::4]
        outside = table[~footprint.dilated(15.0).contains(points[table, :2])]
        test = ChangeTest.fit(current, reference, np.round(self.cloud.pixels[outside]).astype(np.int64))
        if test is None:
            return None
        changed = test.changed(current, reference)
        self._changed_left = changed
        # The right image against its own reference, for the outline's left/right check (cellctl.vision.checks).
        right_table = self.cloud.pixels[outside] - np.column_stack(
            [self.cloud.disparity[outside], np.zeros(len(outside))]
        )
        right_test = ChangeTest.fit(self.cloud.rectified[1], self.taught.right, np.round(right_table).astype(np.int64))
        if right_test is not None:
            self.changed_right = right_test.changed(self.cloud.rectified[1], self.taught.right)
        # The foot of a leaning wall, not the table: a cast shadow changes the image but lies at z ~ 0.
        near = np.flatnonzero((points[:, 2] > WALL_FOOT_MM) & (points[:, 2] <= self.min_height))
        near = near[footprint.dilated(EDGE_BAND_MM).contains(points[near, :2])]
        candidates = np.concatenate([high, near])
        x, y = np.round(self.cloud.pixels[candidates]).astype(np.int64).T
        return np.sort(candidates[changed[y, x]])

    def _colour_filter(self, points: np.ndarray, footprint: Footprint, high: np.ndarray) -> np.ndarray:
        """Which of the `high` points (indices) are sole-coloured (all when the colours do not separate).

        Linear discriminant between the table's colour (plane inliers outside the sole) and the sole's
        (points well inside the footprint), thresholded half way between the two means, which is where a
        pixel half covered by the sole lies: the edge stays where it is.
        """
        colours = self.cloud.colors
        # The table's colour statistics from every 4th table point (~150000): as exact, at a quarter the time.
        table = np.flatnonzero(np.abs(points[:, 2]) < TABLE_INLIER_MM)[::4]
        interior = high[footprint.eroded(5.0).contains(points[high, :2])]
        outside = table[~footprint.dilated(10.0).contains(points[table, :2])]
        if interior.size < 100 or outside.size < 100:
            return np.ones(len(high), bool)
        sole_c, table_c = colours[interior].astype(np.float64), colours[outside].astype(np.float64)
        pooled = 0.5 * (np.cov(sole_c.T) + np.cov(table_c.T)) + np.eye(3) * 1e-3
        difference = sole_c.mean(axis=0) - table_c.mean(axis=0)
        direction = np.linalg.solve(pooled, difference)
        self.separation = float(np.sqrt(direction @ difference))
        if self.separation < MIN_COLOUR_SEPARATION:
            return np.ones(len(high), bool)
        self.colour_filter = True
        threshold = direction @ (0.5 * (sole_c.mean(axis=0) + table_c.mean(axis=0)))
        return colours[high].astype(np.float64) @ direction > threshold

    def _cut_by_border(self, index: np.ndarray) -> tuple[FailureKind | None, str | None]:
        """Failure kind and reason if the sole reaches the edge of what both cameras see (else None, None)."""
        if index.size == 0:
            return FailureKind.NO_SOLE, "no sole in view: no sole points left after outlier removal"
        width, height = self.cloud.image_size
        x, y = self.cloud.pixels[index].T
        d = self.cloud.disparity[index]
        m = BORDER_MARGIN_PX
        # x - d < m: the right camera does not see the point (it left the right image on the left).
        at_edge = (x < m) | (x > width - 1 - m) | (y < m) | (y > height - 1 - m) | (x - d < m)
        if np.any(at_edge):
            return FailureKind.SOLE_AT_BORDER, (
                "sole cut by the image border: move the sole towards the middle of the table "
                f"({int(at_edge.sum())} sole points within {m} px of the edge of the common view)"
            )
        return None, None

    def _fail(self, failure: FailureKind, reason: str) -> ReconstructionRefused:
        return self._refused(failure, reason)

    def _refused(self, failure: FailureKind, reason: str, **sole: Any) -> ReconstructionRefused:
        """A refusal with what this run found about the table and the cloud, plus the sole's points if any."""
        return ReconstructionRefused(
            failure=failure,
            reason=reason,
            measured_points=self.measured,
            measured_fraction=self.fraction,
            table_plane=self.plane,
            camera_to_table=self.transform,
            colour_filter=self.colour_filter,
            colour_separation=self.separation,
            timings=self.timings,
            **sole,
        )

    def _result(self, failure: FailureKind | None, reason: str | None, **sole: Any) -> ReconstructionResult:
        """The sole found (or refused with `failure`), with what this run found about the table and the cloud."""
        if failure is not None or reason is not None:
            refused = ("sole_points", "sole_colors", "footprint")
            return self._refused(
                failure or FailureKind.NO_SOLE, reason or "no sole", **{k: sole[k] for k in refused if k in sole}
            )
        assert self.plane is not None and self.transform is not None  # a sole is only found on a table
        return Reconstruction(
            camera_to_table=self.transform,
            table_plane=self.plane,
            colour_filter=self.colour_filter,
            colour_separation=self.separation,
            measured_points=self.measured,
            measured_fraction=self.fraction,
            timings=self.timings,
            calibration=self.cloud.calibration,
            raised=self.raised,
            measured_cells=self.measured_cells,
            taught=self.taught,
            changed_right=self.changed_right,
            **sole,
        )


def _footprint(
    raster: Footprint, every: np.ndarray, sole_xy: np.ndarray, open_mm: float = FOOTPRINT_OPEN_MM
) -> Footprint:
    """Largest region of `raster` where most measured points of a cell (`every`, per cell) are sole points
    (`sole_xy`), closed and hole-free."""
    sole = raster.counts(sole_xy)
    # A cell is sole if most of its own points are; cells without points are decided by the closing.
    mask = ((sole > 0) & (2 * sole >= every)).astype(np.uint8)
    return Footprint(mask, raster.origin, raster.cell_mm).morphology(close_mm=2.0, open_mm=open_mm).largest_region()
