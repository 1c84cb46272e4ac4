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

The filters and checks one run applies (colour, change against the taught table, border, sole mask) are
in cellctl.vision.sole_region; this module keeps the result types and the run's order.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import open3d as o3d

from cellctl.errors import FailureKind
from cellctl.vision.calibration import Calibration
from cellctl.vision.change import ChangeTest
from cellctl.vision.cloud import StereoCloud
from cellctl.vision.footprint import Footprint
from cellctl.vision.image_noise import MAX_IMAGE_NOISE_DN, NOISY_IMAGE_REMEDY, image_noise_dn
from cellctl.vision.sole_region import (
    MIN_COLOUR_SEPARATION,
    MIN_SOLE_AREA_MM2,
    PointSpread,
    change_split,
    colour_split,
    cut_by_border,
    depth_step,
    point_spread,
    sole_mask,
    unmeasured_fraction,
    why_no_sole,
    without_outliers,
)
from cellctl.vision.table import TablePlane, find_and_refine_table, not_the_table
from cellctl.vision.teach import TaughtTable, check_drift

MIN_HEIGHT_MM = 3.0  # points lower than this belong to the table (its height noise is well below 1 mm)
MAX_HEIGHT_MM = 150.0  # anything higher is not a sole lying on the table (a hand, the robot)
MIN_VALID_FRACTION = 0.15  # fewer measured pixels than this: the pair cannot be trusted
FOOTPRINT_CELL_MM = 0.25  # below the pixel spacing (0.39 mm): the outline is not quantised to a coarse grid
FOOTPRINT_OPEN_MM = 1.0  # specks thinner than this go; a pointed toe's tip (radius >= 0.5 mm) stays
COLOUR_OPEN_MM = 2.0  # the same without a taught table: the colour edge's noise needs the wider opening


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
    # The same pair for the surface's image fits (cellctl.vision.surface): round the sole interpolated from the
    # raw images without rounding (`Calibration.rectify_grey`), elsewhere `rectified`; None: `rectified` it is.
    surface_grey: tuple[np.ndarray, np.ndarray] | None = None
    sole_mask: np.ndarray | None = None  # bool, rectified left pixels on the sole (off its very edge)
    # The depth step on the footprint's raster, for the outline's self-check (cellctl.vision.checks):
    raised: Footprint | None = None  # cells where most measured points rise above the table
    measured_cells: Footprint | None = None  # cells with any measured point
    # Cells with a measured point at the table's height, not dilated: where depth saw the table (image_edge).
    table_points: Footprint | None = None
    taught: TaughtTable | None = None  # the taught table the sole was found against, if any
    changed_right: np.ndarray | None = None  # bool, rectified right pixels changed against the taught table
    changed_left: np.ndarray | None = None  # the same for the left image
    unmeasured_fraction: float = 0.0  # of the sole's changed pixels without depth (glare, no texture)
    change_test: ChangeTest | None = None  # the left image's against the taught table, if any
    image_noise_dn: float | None = None  # the rectified left image's noise (image_noise.image_noise_dn), if read
    soft_edges: bool = False  # the images are soft at the sole's edge (cellctl.vision.edge_blur): a lens out of focus
    from_mean: bool = False  # measured on the mean of the cycle's exposures: the last one was noisier than a clean one
    # Where the surface's image fits read the mean of several exposures (`surface_grey`): what averaging removed from
    # the last exposure (image_noise.exposure_noise_dn), and how many exposures, where the caller said.
    exposure_noise_dn: float | None = None
    surface_exposures: int | None = None

    @property
    def surface_averaged(self) -> bool:
        """The surface's image fits read the mean of several exposures."""
        return self.exposure_noise_dn is not None

    @property
    def pixel_mm(self) -> float | None:
        """A rectified pixel's footprint on the table (mm): the left camera's height above it over the focal
        length; None without a stereo calibration (a true depth map)."""
        if self.calibration is None:
            return None
        return abs(float(self.camera_to_table[2, 3])) / self.calibration.focal_px

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


class _RunState:
    """What one run of the segmentation has learnt so far (table, transform, filters, the depth step and the
    change masks), and the result types built from it: the state the steps of `Segmentation` share."""

    def __init__(
        self,
        cloud: StereoCloud,
        table_plane: TablePlane | None,
        min_height_mm: float,
        taught: TaughtTable | None = None,
        image_noise: float | None = None,
    ) -> None:
        """image_noise: image_noise_dn of the cloud's rectified left image, when the caller has read it."""
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
        self.table_points: Footprint | None = None  # cells with a measured point at the table's height
        self.changed_right: np.ndarray | None = None
        self._changed_left: np.ndarray | None = None
        self.change_test: ChangeTest | None = None
        self.image_noise = image_noise  # image_noise_dn of the rectified left image, once read

    def _refused(self, failure: FailureKind, reason: str, **sole: Any) -> ReconstructionRefused:
        """A refusal with what this run found about the table and the cloud, plus the sole's points if any."""
        return ReconstructionRefused(failure=failure, reason=reason, **self._found(), **sole)

    def _found(self) -> dict[str, Any]:
        """What this run found about the table and the cloud: every result carries it, refused or not."""
        return dict(
            measured_points=self.measured,
            measured_fraction=self.fraction,
            table_plane=self.plane,
            camera_to_table=self.transform,
            colour_filter=self.colour_filter,
            colour_separation=self.separation,
            timings=self.timings,
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
            **self._found(),
            calibration=self.cloud.calibration,
            raised=self.raised,
            measured_cells=self.measured_cells,
            table_points=self.table_points,
            taught=self.taught,
            changed_right=self.changed_right,
            changed_left=self._changed_left,
            change_test=self.change_test,
            image_noise_dn=self.image_noise,
            **sole,
        )


class Segmentation(_RunState):
    """One run of the segmentation; a class only to keep the steps short and their shared state named."""

    def run(self) -> ReconstructionResult:
        if self.fraction < MIN_VALID_FRACTION:
            return self._refused(
                FailureKind.TOO_FEW_POINTS,
                f"too few measured points: {self.measured} ({100 * self.fraction:.1f} % of the image, need "
                f"{100 * MIN_VALID_FRACTION:.0f} %); check lighting, focus, the calibration and the depth range",
            )
        if self.cloud.rectified is not None:
            if self.image_noise is None:
                self.image_noise = image_noise_dn(self.cloud.rectified[0])
            noise = self.image_noise
            if noise > MAX_IMAGE_NOISE_DN:
                return self._refused(
                    FailureKind.SURFACE_NOT_MEASURED,
                    f"the image is too noisy to measure the surface within tolerance: sensor noise {noise:.1f} DN "
                    f"(at most {MAX_IMAGE_NOISE_DN:g}); {NOISY_IMAGE_REMEDY}",
                )
        start = time.perf_counter()
        if self.plane is None:
            self.plane = find_and_refine_table(self.cloud)
        self.timings["table_plane"] = time.perf_counter() - start
        if self.plane is None:
            return self._refused(
                FailureKind.NO_TABLE, "no table plane found: the table must fill most of the view, below the sole"
            )
        if self.taught is not None:
            drift = check_drift(self.taught, self.cloud.points)
            self.timings["table_drift"] = time.perf_counter() - start
            if drift.problem is not None:
                return self._refused(FailureKind.TABLE_MOVED, drift.problem)
        transform = self.plane.camera_to_table()
        points = self.cloud.points @ transform[:3, :3].T + transform[:3, 3]
        if problem := not_the_table(points):
            return self._refused(FailureKind.NO_TABLE, problem)
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
        # Rows of points are gathered with np.take (the same rows; numpy's row indexing costs ~3 x as much on
        # ~10^5 rows); the raster kernels read the x y of x y z rows in place.
        high_points = np.take(points, high, axis=0)
        raster = Footprint.empty_like(high_points, FOOTPRINT_CELL_MM)
        every = raster.counts(xy)  # all measured points per cell: "most of a cell's points" needs them
        high_counts = raster.counts(high_points)
        footprint = _footprint(raster, every, high_counts)
        if footprint.area_mm2 < MIN_SOLE_AREA_MM2:
            return self._no_sole(points, no_sole)
        self.table_points = Footprint(
            ((every > high_counts) & (every > 0)).astype(np.uint8), raster.origin, raster.cell_mm
        )
        if self.taught is not None:
            change = change_split(self.cloud, self.taught, points, footprint, high, self.min_height)
            if change is None:
                return self._refused(
                    FailureKind.TABLE_MOVED,
                    "too little of the taught table is visible around the sole to compare with: clear the table",
                )
            keep, self._changed_left, self.changed_right = change.sole, change.changed_left, change.changed_right
            self.change_test = change.test
            if len(change.shadowed):
                # Depth carried over a cast shadow's band (cellctl.vision.shadow_band): not measured there, for the
                # footprint and the depth step alike.
                carried = raster.counts(np.take(points, change.shadowed, axis=0))
                every, high_counts = every - carried, high_counts - carried
        else:
            colour = colour_split(self.cloud.colors, points, footprint, high)
            keep, self.colour_filter, self.separation = high[colour.sole], colour.applied, colour.separation
        self.raised, self.measured_cells = depth_step(raster, every, high_counts)
        if self.taught is None and not self.colour_filter:
            # Without the colour edge, matching halos widen the sole by 1-5 mm (simulated soles): no length.
            return self._refused(
                FailureKind.COLOURS_TOO_SIMILAR,
                f"sole and table colours too similar to find the sole's edge (they differ by "
                f"{self.separation:.1f} standard deviations, need {MIN_COLOUR_SEPARATION:g}): use a table "
                "surface that contrasts with the sole",
            )
        kept = np.take(points, keep, axis=0)
        above = np.flatnonzero(kept[:, 2] > self.min_height)  # of keep; the foot of a wall (lower): outline only
        self.timings["background"] = time.perf_counter() - start
        start = time.perf_counter()
        # Isolated specks are told only against a taught table (`_footprint_votes`): on the colour split's footprint
        # without one they took edge cells of black soles, whose sparse depth there the colour test keeps
        # (standard sole 1: a glue point 0.90 -> 1.00 mm off).
        spread = point_spread(self.cloud, np.take(keep, above), points) if self.taught is not None else None
        spent = time.perf_counter() - start
        start = time.perf_counter()
        votes = _footprint_votes(raster, kept, above, spread)
        # The colour edge is noisier than the change edge (a black sole's colour noise): it keeps the coarser
        # opening it was tuned with; the change edge keeps a pointed toe's tip.
        footprint = _footprint(raster, every, votes, FOOTPRINT_OPEN_MM if self.taught else COLOUR_OPEN_MM)
        if footprint.area_mm2 < MIN_SOLE_AREA_MM2:
            # As before the colour or change test (`_no_sole`): a sole-sized change on the taught table whose depth
            # is mostly lost (glare on a glossy grey sole: 5000 mm^2 raised, 4800 left after the votes, matrix sole
            # 40027) is a sole too little measured, not "no sole in view".
            return self._no_sole(points, "no sole in view: the region above the table has the table's colour")
        inside = footprint.contains(np.take(kept, above, axis=0))
        index = np.take(keep, above[inside])
        self.timings["background"] += time.perf_counter() - start
        start = time.perf_counter()
        index = without_outliers(self.cloud, index, points, None if spread is None else spread.distance[inside])
        self.timings["outliers"] = spent + time.perf_counter() - start
        failure, reason = cut_by_border(self.cloud, index)
        # A refusal keeps no mask (`_result`): neither it nor the edge's sharpness is read for one.
        mask, soft = (None, False) if failure is not None or reason is not None else sole_mask(self.cloud, index)
        return self._result(
            failure,
            reason,
            sole_points=np.take(points, index, axis=0),
            sole_colors=np.take(self.cloud.colors, index, axis=0),
            sole_pixels=np.take(self.cloud.pixels, index, axis=0),
            footprint=footprint,
            rectified=self.cloud.rectified,
            sole_mask=mask,
            soft_edges=soft,
            unmeasured_fraction=unmeasured_fraction(self.cloud, self._changed_left, index),
        )

    def _no_sole(self, points: np.ndarray, reason: str) -> ReconstructionRefused:
        return self._refused(*why_no_sole(self.cloud, self.taught, self.plane, points, reason))


def _footprint_votes(raster: Footprint, kept: np.ndarray, above: np.ndarray, spread: PointSpread | None) -> np.ndarray:
    """The sole's points per cell of `raster` that vote for the footprint: the points `kept` (N x 3) less the
    isolated specks of depth among those `above` (indices into kept, with their `spread`).

    Over a dark shadow band beside the sole the matcher measures nothing but a few pixels it gives the sole's
    disparity (beside a black sole, a few of the table's); changed and high, those points made their cells sole
    and the closing joined them into a bulge of the outline, 2 mm beyond the edge over 8 mm on fresh sole 9339
    (docs/sole-benchmark.md, twenty-second round). The outlier removal drops them from the sole's points too."""
    votes = raster.counts(kept)
    if spread is not None and np.any(spread.isolated):
        votes -= raster.counts(np.take(kept, above[spread.isolated], axis=0))
    return votes


def _footprint(raster: Footprint, every: np.ndarray, sole: np.ndarray, open_mm: float = FOOTPRINT_OPEN_MM) -> Footprint:
    """Largest region of `raster` where most measured points of a cell (`every`, per cell) are sole points
    (`sole`, per cell), closed and hole-free."""
    # A cell is sole if most of its own points are; cells without points are decided by the closing.
    mask = ((sole > 0) & (2 * sole >= every)).astype(np.uint8)
    return Footprint(mask, raster.origin, raster.cell_mm).morphology(close_mm=2.0, open_mm=open_mm).largest_region()
