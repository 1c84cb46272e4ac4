"""From a stereo pair to the sole's point cloud in the table frame.

Steps (after Wang et al. 2022, section 2.2.4 and the colour filter of section 3):

1. rectify with the calibration and match with `StereoMatcher` over the disparity range of the working
   depth range (d = f * B / Z); keep only pixels the matcher really measured (left-right check passed);
2. reproject through Q into the rectified left camera frame;
3. find the table plane (RANSAC, refined by least squares) or use a plane stored at set-up, and move
   everything into the table frame (docs/measurements.md);
1b. drop pixels without texture (flat, e.g. clipped): they match anywhere and can pass the LR check;
4. background removal: points at least `min_height_mm` above the table and sole-coloured (the paper's
   colour filter, with the threshold learnt from the scene). The colour filter also removes the halo of
   table pixels that window-based matching drags onto the sole's disparity at its edge (edge fattening,
   1-5 mm on simulated soles); a sole whose colour does not separate from the table's is therefore not
   measured (invalid, with the reason) rather than measured too long;
5. the sole is the largest connected region of the footprint raster (cellctl.footprint), holes filled;
6. statistical outlier removal (Open3D's rule, neighbours found on the pixel grid) on the sole's points, and a mask of the sole's pixels so that
   heights can be refined on the images (cellctl.surface, cellctl.subpixel).

`SoleReconstructor.reconstruct(left, right)` runs all of it; `points_from_disparity` and `segment` are the
two halves, so a cloud from another source (e.g. the simulator's true depth) can be segmented the same way.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import open3d as o3d

from cellctl.calibration import Calibration
from cellctl.failures import FailureKind, MeasurementInputError
from cellctl.footprint import Footprint
from cellctl.subpixel import refine_patches

DEFAULT_DEPTH_RANGE_MM: tuple[float, float] = (450.0, 650.0)  # covers a table 550 mm below the rig and soles on it
MIN_HEIGHT_MM = 3.0  # points lower than this belong to the table (its height noise is well below 1 mm)
MAX_HEIGHT_MM = 150.0  # anything higher is not a sole lying on the table (a hand, the robot)
TABLE_INLIER_MM = 1.5  # RANSAC inlier distance for the table plane
MIN_VALID_FRACTION = 0.15  # fewer measured pixels than this: the pair cannot be trusted
MIN_SOLE_AREA_MM2 = 5000.0  # smaller regions are not a sole (the smallest soles are ~ 15000 mm^2)
BORDER_MARGIN_PX = 8  # a sole closer than this to the edge of what both cameras see is cut off
FOOTPRINT_CELL_MM = 0.25  # below the pixel spacing (0.39 mm): the outline is not quantised to a coarse grid
SOLE_MASK_ERODE_PX = 1  # sub-pixel fits keep this far from the edge: its pixels mix sole and table
MIN_TEXTURE_DN = 0.5  # grey-level std over 5 x 5 px below which a pixel has nothing to match (sensor noise is ~1)
MIN_COLOUR_SEPARATION = 4.0  # sole and table colours this many standard deviations apart: filter by colour
# Only really measured pixels (no fill); the widest census window, because the sole's texture is weak:
# on simulated soles it halves the matcher's height noise for the same time.
SOLE_MATCHER_PARAMS: dict[str, object] = {"fill": "none", "census_window": (9, 7)}


@dataclass
class StereoCloud:
    """Measured points of one pair in the rectified left camera frame (mm), with their pixels and colours."""

    points: np.ndarray  # N x 3 float64
    colors: np.ndarray  # N x 3 float32 BGR 0..255, from the (slightly smoothed) rectified left image
    pixels: np.ndarray  # N x 2 float64 (x, y) in the rectified left image
    disparity: np.ndarray  # N float64, px
    image_size: tuple[int, int]  # (width, height) of the rectified images
    timings: dict[str, float] = field(default_factory=dict)
    rectified: tuple[np.ndarray, np.ndarray] | None = None  # grey float32 pair, for sub-pixel refinement
    calibration: Calibration | None = None


@dataclass(frozen=True)
class TablePlane:
    """The table as n . p + d = 0 in the rectified left camera frame, n unit and pointing towards the camera."""

    normal: np.ndarray
    offset: float

    @classmethod
    def fit(cls, points: np.ndarray) -> TablePlane:
        """Least-squares plane through points (N x 3), oriented towards the camera at the origin."""
        centre = points.mean(axis=0)
        centred = points - centre
        # The normal is the scatter matrix's eigenvector of least spread: the same as the SVD's last right
        # singular vector, from a 3 x 3 problem instead of an N x 3 one (N ~ 10^6).
        _, vectors = np.linalg.eigh(centred.T @ centred)
        normal = vectors[:, 0]
        offset = -float(normal @ centre)
        if offset < 0:  # the camera (origin) must be on the positive side
            normal, offset = -normal, -offset
        return cls(normal, offset)

    def heights(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.offset

    def camera_to_table(self) -> np.ndarray:
        """4 x 4 rigid transform from the rectified left camera frame to the table frame.

        Origin: the foot of the camera centre on the table; z: the normal; x: the camera's x axis
        projected onto the table (docs/measurements.md).
        """
        z = self.normal
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        origin = -self.offset * z
        transform = np.eye(4)
        transform[:3, :3] = np.vstack([x, y, z])
        transform[:3, 3] = -transform[:3, :3] @ origin
        return transform


@dataclass
class Reconstruction:
    """The sole's points in the table frame, or the reason there are none."""

    sole_points: np.ndarray  # N x 3, table frame, mm
    sole_colors: np.ndarray  # N x 3 BGR 0..255
    sole_pixels: np.ndarray  # N x 2 (x, y) in the rectified left image
    footprint: Footprint | None
    camera_to_table: np.ndarray | None  # 4 x 4, rectified left camera -> table
    table_plane: TablePlane | None
    colour_filter: bool  # whether the colour filter was applied
    colour_separation: float  # sole/table colour distance in standard deviations
    measured_points: int
    measured_fraction: float
    reason: str | None = None  # why there is no sole, in words (None: valid)
    failure: FailureKind | None = None  # the same, as a kind a program can act on
    timings: dict[str, float] = field(default_factory=dict)
    calibration: Calibration | None = None
    rectified: tuple[np.ndarray, np.ndarray] | None = None  # grey float32 rectified pair
    sole_mask: np.ndarray | None = None  # bool, rectified left pixels on the sole (off its very edge)

    @property
    def valid(self) -> bool:
        return self.reason is None

    def point_cloud(self) -> o3d.geometry.PointCloud:
        """The sole as an Open3D cloud with RGB colours (for PLY output and viewing)."""
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(self.sole_points, np.float64)))
        # Contiguous float64: Open3D copies that in one go, anything else element by element (~50 ms per cycle).
        rgb = np.ascontiguousarray(np.clip(self.sole_colors[:, ::-1] / 255.0, 0.0, 1.0), np.float64)
        cloud.colors = o3d.utility.Vector3dVector(rgb)
        return cloud


def disparity_range(calib: Calibration, depth_range_mm: tuple[float, float]) -> tuple[int, int]:
    """(min_disparity, num_disparities) covering a working depth range, from d = f * B / Z."""
    near, far = float(depth_range_mm[0]), float(depth_range_mm[1])
    if not (0 < near < far):
        raise ValueError(f"depth range must be two distances MIN < MAX in mm, got {near:g} {far:g}")
    fb = calib.focal_px * calib.baseline_mm
    lowest = int(np.floor(fb / far))
    highest = int(np.ceil(fb / near))
    width = calib.image_size[0]
    if highest >= width:
        raise ValueError(
            f"depth range {near:g}-{far:g} mm needs disparities up to {highest} px, more than the image is wide "
            f"({width} px): raise the near limit"
        )
    return lowest, highest - lowest + 1


class SoleReconstructor:
    """Rectify, match, reproject and segment the sole; one instance per rig, reused across cycles."""

    def __init__(
        self,
        calib: Calibration,
        depth_range_mm: tuple[float, float] = DEFAULT_DEPTH_RANGE_MM,
        table_plane: TablePlane | None = None,
        min_height_mm: float = MIN_HEIGHT_MM,
        **matcher_params: object,
    ) -> None:
        self.calib = calib
        self.depth_range_mm = (float(depth_range_mm[0]), float(depth_range_mm[1]))
        self.min_disparity, self.num_disparities = disparity_range(calib, self.depth_range_mm)
        self.table_plane = table_plane
        self.min_height_mm = float(min_height_mm)
        self._matcher_params = {**SOLE_MATCHER_PARAMS, **matcher_params}
        if self._matcher_params["fill"] != "none":
            # Every valid pixel of the final map is taken as measured (points_from_disparity).
            raise ValueError(f"the sole reconstruction needs fill='none' (got {self._matcher_params['fill']!r}): "
                             "filled disparities are guesses, not measurements")
        self._matcher = None

    def reconstruct(self, left: np.ndarray, right: np.ndarray) -> Reconstruction:
        """The sole's cloud from one raw (unrectified) stereo pair."""
        return self.segment(self.points_from_disparity(left, right))

    def points_from_disparity(self, left: np.ndarray, right: np.ndarray) -> StereoCloud:
        """Rectify, match and reproject: every really measured pixel as a 3-D point."""
        for image in (left, right):
            try:
                self.calib.check_image(image)
            except ValueError as exc:
                raise MeasurementInputError(FailureKind.CALIBRATION_MISMATCH, str(exc)) from None
        timings: dict[str, float] = {}
        start = time.perf_counter()
        rect_left, rect_right = self.calib.rectify(left, right)
        timings["rectify"] = time.perf_counter() - start
        start = time.perf_counter()
        # The final map alone (int16, x DISP_SCALE): without fill ("none") the medians keep unmeasured pixels
        # invalid, so a valid pixel of it is one that passed the left-right check. compute_detailed would
        # convert five maps to float for nothing.
        fixed = self._stereo_matcher().compute_fixed(rect_left, rect_right)
        timings["match"] = time.perf_counter() - start
        start = time.perf_counter()
        from cellctl.stereo import DISP_SCALE, INVALID

        grey_left, grey_right = _grey(rect_left), _grey(rect_right)
        # A flat patch (clipped highlight, covered lens) matches at any disparity and can still pass the
        # left-right check: such pixels are not measurements.
        measured = (fixed != INVALID) & (_local_std(grey_left) >= MIN_TEXTURE_DN)
        ys, xs = np.nonzero(measured)
        disparity = fixed[ys, xs] / float(DISP_SCALE)
        # Only the measured pixels through Q ([X Y Z W] = Q [x y d 1], cv2.reprojectImageTo3D's formula), as
        # a perspective transform of (x, y, d): no H x W x 3 map to build and gather from.
        pixel_disparity = np.column_stack([xs, ys, disparity]).reshape(-1, 1, 3)
        cloud = StereoCloud(
            points=cv2.perspectiveTransform(pixel_disparity, self.calib.Q).reshape(-1, 3),
            colors=_smoothed_colours(rect_left)[ys, xs],
            pixels=np.column_stack([xs, ys]).astype(np.float64),
            disparity=disparity,
            image_size=self.calib.image_size,
            timings=timings,
            rectified=(grey_left, grey_right),
            calibration=self.calib,
        )
        timings["reproject"] = time.perf_counter() - start
        return cloud

    def segment(self, cloud: StereoCloud) -> Reconstruction:
        """Table plane, background removal, largest region and outlier removal on a measured cloud."""
        return _Segmentation(cloud, self.table_plane, self.min_height_mm).run()

    def _stereo_matcher(self):  # noqa: ANN202 - StereoMatcher is imported lazily (compiled core)
        if self._matcher is None:
            from cellctl.stereo import StereoMatcher

            self._matcher = StereoMatcher(self.min_disparity, self.num_disparities, **self._matcher_params)
        return self._matcher


def _grey(image: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    return grey.astype(np.float32)


def _local_std(grey: np.ndarray, size: int = 5) -> np.ndarray:
    mean = cv2.blur(grey, (size, size))
    return np.sqrt(np.maximum(cv2.blur(grey * grey, (size, size)) - mean * mean, 0.0))


def _smoothed_colours(image: np.ndarray) -> np.ndarray:
    """Per-pixel colour for the colour filter: a 3 x 3 mean tames sensor noise but keeps the edge position."""
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return cv2.boxFilter(image, cv2.CV_32F, (3, 3))  # float output straight from uint8: no rounding


class _Segmentation:
    """One run of the segmentation; a class only to keep the steps short and their shared state named."""

    def __init__(self, cloud: StereoCloud, table_plane: TablePlane | None, min_height_mm: float) -> None:
        self.cloud = cloud
        self.plane = table_plane
        self.min_height = min_height_mm
        self.timings = dict(cloud.timings)
        width, height = cloud.image_size
        self.measured = len(cloud.points)
        self.fraction = self.measured / float(width * height)
        self.transform: np.ndarray | None = None
        self.colour_filter = False
        self.separation = 0.0

    def run(self) -> Reconstruction:
        if self.fraction < MIN_VALID_FRACTION:
            return self._fail(
                FailureKind.TOO_FEW_POINTS,
                f"too few measured points: {self.measured} ({100 * self.fraction:.1f} % of the image, need "
                f"{100 * MIN_VALID_FRACTION:.0f} %); check lighting, focus, the calibration and the depth range"
            )
        start = time.perf_counter()
        if self.plane is None:
            self.plane = _find_table(self.cloud.points)
            if self.plane is not None and self.cloud.rectified is not None:
                self.plane = _refine_table(self.cloud, self.plane)
        self.timings["table_plane"] = time.perf_counter() - start
        if self.plane is None:
            return self._fail(
                FailureKind.NO_TABLE, "no table plane found: the table must fill most of the view, below the sole"
            )
        transform = self.plane.camera_to_table()
        points = self.cloud.points @ transform[:3, :3].T + transform[:3, 3]
        # The table frame's z is the height above the plane: no second pass over the ~10^6 points for it.
        below = float(np.mean(points[:, 2] < -5.0 * TABLE_INLIER_MM))
        if below > 0.05:
            return self._fail(
                FailureKind.NO_TABLE,
                f"{100 * below:.0f} % of the points lie below the table plane: the plane found is not the table"
            )
        self.transform = transform
        return self._sole(points)

    def _sole(self, points: np.ndarray) -> Reconstruction:
        start = time.perf_counter()
        xy, z = points[:, :2], points[:, 2]
        # Indices rather than masks: most points are table, and only the high ones can be sole.
        high = np.flatnonzero((z > self.min_height) & (z < MAX_HEIGHT_MM))
        no_sole = f"no sole in view: nothing larger than {MIN_SOLE_AREA_MM2:.0f} mm^2 above the table"
        if high.size == 0:
            return self._fail(FailureKind.NO_SOLE, no_sole)
        # One raster for both footprints, over the high points only (cells elsewhere cannot be sole); its
        # cells lie on the same lattice whatever it covers (Footprint.empty_like).
        raster = Footprint.empty_like(xy[high], FOOTPRINT_CELL_MM)
        every = raster.counts(xy)  # all measured points per cell: "most of a cell's points" needs them
        footprint = _footprint(raster, every, xy[high])
        if footprint.area_mm2 < MIN_SOLE_AREA_MM2:
            return self._fail(FailureKind.NO_SOLE, no_sole)
        keep = high[self._colour_filter(points, footprint, high)]
        if not self.colour_filter:
            # Without the colour edge, matching halos widen the sole by 1-5 mm (simulated soles): no length.
            return self._fail(
                FailureKind.COLOURS_TOO_SIMILAR,
                f"sole and table colours too similar to find the sole's edge (they differ by "
                f"{self.separation:.1f} standard deviations, need {MIN_COLOUR_SEPARATION:g}): use a table "
                "surface that contrasts with the sole"
            )
        footprint = _footprint(raster, every, xy[keep])
        if footprint.area_mm2 < MIN_SOLE_AREA_MM2:
            return self._fail(FailureKind.NO_SOLE, "no sole in view: the region above the table has the table's colour")
        index = keep[footprint.contains(xy[keep])]
        self.timings["background"] = time.perf_counter() - start
        start = time.perf_counter()
        index = self._without_outliers(index, points)
        self.timings["outliers"] = time.perf_counter() - start
        failure, reason = self._cut_by_border(index)
        return self._result(
            failure, reason, sole_points=points[index], sole_colors=self.cloud.colors[index],
            sole_pixels=self.cloud.pixels[index], footprint=footprint, rectified=self.cloud.rectified,
            sole_mask=self._sole_mask(index),
        )

    def _without_outliers(self, index: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The points (indices) that statistical outlier removal keeps."""
        calib = self.cloud.calibration
        if calib is None:  # not a stereo cloud, so not one point per rectified pixel (e.g. a true depth map)
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[index]))
            _, inliers = cloud.remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0)
            return index[np.asarray(inliers, dtype=np.int64)]
        spacing = calib.baseline_mm / self.cloud.disparity[index]  # between pixels at the point: Z / f = B / d
        return index[_statistical_inliers(self.cloud.pixels[index], points[index], spacing)]

    def _sole_mask(self, index: np.ndarray) -> np.ndarray | None:
        """Rectified left pixels on the sole: measured ones, small holes closed, the edge pixel dropped."""
        if self.cloud.rectified is None:
            return None
        width, height = self.cloud.image_size
        mask = np.zeros((height, width), np.uint8)
        x, y = np.round(self.cloud.pixels[index]).astype(int).T
        mask[y, x] = 1
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
        return cv2.erode(mask, np.ones((SOLE_MASK_ERODE_PX * 2 + 1,) * 2, np.uint8)) > 0

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

    def _fail(self, failure: FailureKind, reason: str) -> Reconstruction:
        return self._result(failure, reason, sole_points=np.zeros((0, 3)), sole_colors=np.zeros((0, 3)),
                            sole_pixels=np.zeros((0, 2)), footprint=None)

    def _result(self, failure: FailureKind | None, reason: str | None, **sole: Any) -> Reconstruction:
        """A Reconstruction with what this reconstructor found about the table and the cloud, plus `sole`."""
        return Reconstruction(
            camera_to_table=self.transform, table_plane=self.plane, colour_filter=self.colour_filter,
            colour_separation=self.separation, measured_points=self.measured, measured_fraction=self.fraction,
            reason=reason, failure=failure, timings=self.timings, calibration=self.cloud.calibration, **sole,
        )


def _find_table(points: np.ndarray, sample: int = 60000, seed: int = 0, refit_stride: int = 4) -> TablePlane | None:
    """RANSAC (Open3D) on a subsample, then a least-squares refit to the inliers of every `refit_stride`-th point.

    The refit matters: heights are measured from this plane, and RANSAC's three-point hypothesis on a
    subsample is only good to about the inlier distance. A quarter of the points (~200000 table points)
    fixes the plane to about a micrometre of statistical error; all of them only cost more time.
    """
    rng = np.random.default_rng(seed)
    subset = points[rng.choice(len(points), size=min(sample, len(points)), replace=False)]
    o3d.utility.random.seed(seed)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(subset))
    model, inliers = cloud.segment_plane(distance_threshold=TABLE_INLIER_MM, ransac_n=3, num_iterations=300)
    if len(inliers) < 0.2 * len(subset):
        return None
    plane = TablePlane(np.asarray(model[:3], np.float64), float(model[3]))
    scale = np.linalg.norm(plane.normal)
    plane = TablePlane(plane.normal / scale, plane.offset / scale)
    spread = points[::refit_stride]  # measured pixels in image order: a stride samples the whole view
    for _ in range(2):  # refit, then refit once more on the refined inliers
        near = np.abs(plane.heights(spread)) < TABLE_INLIER_MM
        plane = TablePlane.fit(spread[near])
    return plane


def _refine_table(cloud: StereoCloud, plane: TablePlane, spacing_px: int = 80, radius_px: float = 16.0) -> TablePlane:
    """The table plane fitted on the images: disparity planes of table patches (cellctl.subpixel), reprojected.

    Every height is measured from this plane, and the matcher's table disparities carry a bias of a few
    hundredths of a pixel (~0.1 mm of height on simulated scenes) that a fit to its points keeps. Local
    patches on a grid rather than one plane over the whole table: each patch gets its own brightness
    correction, so the cameras' different vignetting cannot tilt the plane.
    """
    width, height = cloud.image_size
    near = np.abs(plane.heights(cloud.points)) < TABLE_INLIER_MM
    mask = np.zeros((height, width), bool)
    x, y = np.round(cloud.pixels[near]).astype(int).T
    mask[y, x] = True
    gx, gy = np.meshgrid(np.arange(spacing_px // 2, width, spacing_px), np.arange(spacing_px // 2, height, spacing_px))
    centres = np.column_stack([gx.ravel(), gy.ravel()]).astype(np.float64)
    centres = centres[mask[centres[:, 1].astype(int), centres[:, 0].astype(int)]]
    if len(centres) < 10:
        return plane
    # Start from the plane itself: in rectified images a plane n.p + o = 0 has d = -B (n . (x - cx, y - cy, f)) / o.
    calib = cloud.calibration
    f, cx, cy, baseline = calib.focal_px, calib.P1[0, 2], calib.P1[1, 2], calib.baseline_mm
    n, o = plane.normal, plane.offset
    start = np.column_stack([
        -baseline * (n[0] * (centres[:, 0] - cx) + n[1] * (centres[:, 1] - cy) + n[2] * f) / o,
        np.full(len(centres), -baseline * n[0] / o),
        np.full(len(centres), -baseline * n[1] / o),
    ])
    left, right = cloud.rectified
    fit = refine_patches(left, right, mask, centres, radius_px, start)
    if np.count_nonzero(fit.ok) < 10:
        return plane
    used = fit.ok[fit.ids]
    homogeneous = np.column_stack([fit.xy, fit.disparities(centres), np.ones(len(fit.ids))])[used] @ calib.Q.T
    points, ids = homogeneous[:, :3] / homogeneous[:, 3:4], fit.ids[used]
    refined = TablePlane.fit(points)
    # Patches that do not lie on the table (a missed object, a mismatch) are dropped and the plane refitted.
    starts = np.flatnonzero(np.diff(ids)) + 1  # ids are sorted: one run per patch
    residual = np.array([abs(np.median(h)) for h in np.split(refined.heights(points), starts)])
    patches = ids[np.concatenate([[0], starts])]
    keep = np.isin(ids, patches[residual < max(3.0 * np.median(residual), 0.05)])
    return TablePlane.fit(points[keep])


def _statistical_inliers(pixels: np.ndarray, points: np.ndarray, spacing_mm: np.ndarray) -> np.ndarray:
    """Indices of the points (N x 3, with their pixels N x 2 and pixel spacing N, mm) that are not outliers.

    Open3D's remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0), with neighbours from the image grid.
    """
    mean = _mean_neighbour_distances(pixels, points, spacing_mm)
    return np.flatnonzero(mean <= mean.mean() + 2.0 * mean.std())


def _mean_neighbour_distances(pixels: np.ndarray, points: np.ndarray, spacing_mm: np.ndarray) -> np.ndarray:
    """Each point's mean distance to its 20 nearest points, itself included (N).

    Open3D's remove_statistical_outlier(nb_neighbors=20, std_ratio=2.0) rule: a point is an outlier when this
    exceeds the cloud's mean of it by 2 standard deviations. The neighbours come from the image grid instead
    of a k-d tree (0.07 s instead of Open3D's 0.15 s for ~1.4 10^5 sole points, 2 cores): the sole is a
    height field seen from above, so a point's nearest points are among its nearest pixels. Mostly they are
    the 20 pixels within 2.3 px (5 x 5 without the corners); where that block is not complete or one of the
    16 pixels within 3.2 px is nearer (the sole's edge, holes, steep flanks), the 19 nearest of those 36;
    for the few whose 19 nearest lie farther still, of a 15 x 15 window; for isolated points (spikes, specks;
    rarely any on the sole) a k-d tree. The means agree with Open3D's to 10^-5 mm (float32 sums).
    """
    grid, rows, cols = _point_grid(pixels, points, margin=_WINDOW_HALVES[-1])
    flat = grid.reshape(3, -1)
    at = rows * grid.shape[2] + cols
    centre = flat[:, at]

    def distances(dx: int, dy: int) -> np.ndarray:  # to the pixel (dx, dy) away; inf where not measured
        offset = np.take(flat, at + (dy * grid.shape[2] + dx), axis=1) - centre
        return np.nan_to_num(np.sqrt(np.einsum("ij,ij->j", offset, offset)), nan=np.inf)

    # The 36 pixels within 3.2 px: beyond them the nearest are 3.6 px away.
    near = np.stack([distances(dx, dy) for dx, dy in _NEAR])  # 36 x N
    block = near[: len(_NEAR_BLOCK)]  # the 20 within 2.3 px
    largest = block.max(axis=0)
    second = np.partition(block, -2, axis=0)[-2]
    # Mostly the 19 nearest are the block's 20 but its farthest: complete, and nearer than any other pixel.
    with np.errstate(invalid="ignore"):  # inf - inf where the block is not complete: recomputed below
        mean = (block.sum(axis=0) - largest) / 20.0  # with the point itself (distance 0)
    exact = np.isfinite(largest) & (second <= np.fmin(near[len(_NEAR_BLOCK) :].min(axis=0), 3.5 * spacing_mm))
    rest = np.flatnonzero(~exact)
    nearest = np.partition(near[:, rest], 18, axis=0)[:19]
    mean[rest] = np.sum(np.fmin(nearest, 3.6 * spacing_mm[rest]), axis=0) / 20.0
    exact[rest] = nearest.max(axis=0) <= 0.95 * 3.6 * spacing_mm[rest]
    others = np.flatnonzero(~exact)
    for half in _WINDOW_HALVES:  # larger windows only for the points whose 19 nearest lie farther out
        if others.size == 0:
            break
        window = np.array([(dx, dy) for dy in range(-half, half + 1) for dx in range(-half, half + 1) if dx or dy])
        neighbours = flat[:, at[others, None] + window[:, 1] * grid.shape[2] + window[:, 0]]  # 3 x P x M
        offset = neighbours - centre[:, others, None]
        distance = np.nan_to_num(np.sqrt(np.einsum("ijk,ijk->jk", offset, offset)), nan=np.inf)
        # Pixels outside the window are at least half + 1 px away: that bounds what was not seen.
        beyond = (half + 1) * spacing_mm[others, None]
        nearest = np.partition(distance, 18, axis=1)[:, :19]
        mean[others] = np.sum(np.fmin(nearest, beyond), axis=1) / 20.0
        others = others[np.max(nearest, axis=1) > 0.95 * beyond[:, 0]]  # 5 % margin for perspective
    if others.size:  # isolated points (spikes, specks): their neighbours lie anywhere, ask a k-d tree
        tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
        for k in others:
            mean[k] = np.mean(np.sqrt(tree.search_knn_vector_3d(points[k], 20)[2]))
    return mean


_WINDOW_HALVES = (7, 15, 31, 63)  # 15 x 15 to 127 x 127 pixels, each for fewer points
_NEAR_BLOCK = [(dx, dy) for dy in range(-2, 3) for dx in range(-2, 3) if 0 < dx * dx + dy * dy <= 5]  # 20
_NEAR = _NEAR_BLOCK + [(dx, dy) for dy in range(-3, 4) for dx in range(-3, 4) if 5 < dx * dx + dy * dy <= 10]  # + 16


def _point_grid(pixels: np.ndarray, points: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points as a 3 x H x W float32 image over their pixels' bounding box plus `margin` (NaN elsewhere),
    and each point's (row, col) in it."""
    x, y = pixels.T.astype(np.int64)
    cols, rows = x - int(x.min()) + margin, y - int(y.min()) + margin
    grid = np.full((3, int(rows.max()) + margin + 1, int(cols.max()) + margin + 1), np.nan, np.float32)
    grid[:, rows, cols] = points.T
    return grid, rows, cols


def _footprint(raster: Footprint, every: np.ndarray, sole_xy: np.ndarray) -> Footprint:
    """Largest region of `raster` where most measured points of a cell (`every`, per cell) are sole points
    (`sole_xy`), closed and hole-free."""
    sole = raster.counts(sole_xy)
    # A cell is sole if most of its own points are; cells without points are decided by the closing.
    mask = ((sole > 0) & (2 * sole >= every)).astype(np.uint8)
    return Footprint(mask, raster.origin, raster.cell_mm).morphology(close_mm=2.0, open_mm=2.0).largest_region()
