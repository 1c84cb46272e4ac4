"""Measuring a reconstructed sole: length, heel and toe height and the glue path (docs/measurements.md).

    reconstruction = SoleReconstructor(calib).reconstruct(left, right)
    result = measure_sole(reconstruction)
    if isinstance(result, SoleMeasurement):
        print(result.length_mm, result.heel_height_mm, result.toe_height_mm)
    else:  # MeasurementRefused
        print("not measured:", result.reason, result.failure)

A refusal carries no numbers, only the reason in words and its `FailureKind` (what a program acts on,
e.g. the service's PLC error code), and what was found on the way for pictures: the robot must never get
a silent wrong value.

Over 350 lines (~490): the result types (success and refusal) and the one procedure that fills them,
whose steps refuse in order; the issue 11 rework of its internals is under way, the split after it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.checks import (
    GLUE_COVER_RADIUS_MM,
    OUTLINE_OUTSIDE_MM,
    CheckFailure,
    check_edge_profile,
    check_glue_coverage,
    check_glue_path,
    check_outline_depth,
    check_outline_right,
    hidden_from,
)
from cellctl.vision.defaults import (
    GLUE_OFFSET_MM,
    GLUE_OFFSET_RANGE_MM,
    GLUE_SPACING_MM,
    GLUE_SPACING_RANGE_MM,
    PLAUSIBLE_HEIGHT_MM,
    PLAUSIBLE_LENGTH_MM,
)
from cellctl.vision.footprint import Footprint, snap_to_inset
from cellctl.vision.local_fit import local_planes
from cellctl.vision.reconstruction import Reconstruction, ReconstructionRefused, ReconstructionResult
from cellctl.vision.surface import MIN_CLOUD_POINTS, SoleSurface

MAX_UNMEASURED_FRACTION = 0.05  # of the sole's changed pixels without depth: beyond, blame the lost pixels
HEIGHT_POINT_FRACTION = 0.10  # heights 10 % of the length in from each end
HEIGHT_RADIUS_MM = 10.0  # patch for the heel and toe heights: on weak texture the noise falls with the radius
MIN_HALF_AREA_DIFFERENCE = 0.04  # toe and heel halves closer than this (fraction of area): too close to call
GLUE_FIT_RADIUS_MM = 4.0
GLUE_NORMAL_BASE_MM = 10.0  # second ring of height samples this far inside the path, for the normals
GLUE_OUTLIER_MM = 1.5  # a lone patch height this far from its neighbours' median is a failed fit
GLUE_NORMAL_SMOOTHING_MM = 12.0  # slopes for the normals: width of the local plane fit
GLUE_SMOOTHING_MM = 6.0  # heights along the path: width of the local plane fit, averages the patches' noise
# Gaussian along the outline: removes the raster's staircase (0.25 mm cells) and pixel noise; wider would cut
# the tip of a pointed toe (a 2 mm sigma takes ~1 mm off a 35 degree wedge).
OUTLINE_SMOOTHING_MM = 0.75
# Without a taught table the edge comes from the colour test, whose noise on black soles biases the extreme
# projections (the length) outward by 0.3-0.5 mm at 0.75 mm: the 2 mm it was tuned with.
COLOUR_OUTLINE_SMOOTHING_MM = 2.0
GLUE_OUTLINE_SMOOTHING_MM = 2.0  # the glue line's staircase and pixel noise; its inward normals follow it


@dataclass
class GluePath:
    """Closed path on the sole's top surface, table frame, ordered from the heel end (first point not repeated)."""

    points: np.ndarray  # N x 3, mm
    normals: np.ndarray  # N x 3, unit, nz > 0
    closed: bool = True
    # What the path was made from, for its self-check (cellctl.vision.checks): per point, the height of the
    # surface patch before smoothing along the path, and the patches' own normals smoothed along it.
    raw_z: np.ndarray | None = None
    surface_normals: np.ndarray | None = None

    @property
    def length_mm(self) -> float:
        steps = np.diff(np.vstack([self.points, self.points[:1]]) if self.closed else self.points, axis=0)
        return float(np.linalg.norm(steps, axis=1).sum())


@dataclass
class SoleMeasurement:
    """The measurements of one sole (the success of `MeasurementResult`)."""

    length_mm: float
    heel_height_mm: float
    toe_height_mm: float
    glue_path: GluePath
    points: int  # sole points the measurement rests on
    # Where the numbers come from (table frame), for drawings and diagnostics.
    axis: np.ndarray  # unit heel->toe direction (x, y)
    heel_point: np.ndarray  # (x, y, z) where heel_height_mm is taken
    toe_point: np.ndarray
    outline: np.ndarray  # footprint outline, N x 2
    half_area_difference: float  # (toe half - heel half) / area
    camera_to_table: np.ndarray  # 4 x 4, rectified left camera -> table
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        return True

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (keys of the `cellctl measure --json` output)."""
        path = self.glue_path
        return {
            "length_mm": _round(self.length_mm),
            "heel_height_mm": _round(self.heel_height_mm),
            "toe_height_mm": _round(self.toe_height_mm),
            "glue_path": np.round(path.points, 3).tolist(),
            "glue_normals": np.round(path.normals, 4).tolist(),
            "points": int(self.points),
            "valid": True,
            "reason": None,
            "failure": None,
            "heel_point": np.round(self.heel_point, 3).tolist(),
            "toe_point": np.round(self.toe_point, 3).tolist(),
            "camera_to_table": np.round(self.camera_to_table, 6).tolist(),
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
        }


@dataclass
class MeasurementRefused:
    """No measurements: why (kind for programs, reason for people) and what was found before the refusal
    (None where the measurement did not get that far), for pictures and diagnostics."""

    failure: FailureKind
    reason: str
    points: int  # sole points found
    timings: dict[str, float] = field(default_factory=dict)
    axis: np.ndarray | None = None
    heel_point: np.ndarray | None = None
    toe_point: np.ndarray | None = None
    outline: np.ndarray | None = None
    half_area_difference: float | None = None
    camera_to_table: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return False

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary: the keys of SoleMeasurement.to_dict, without numbers."""
        return {
            "length_mm": None,
            "heel_height_mm": None,
            "toe_height_mm": None,
            "glue_path": [],
            "glue_normals": [],
            "points": int(self.points),
            "valid": False,
            "reason": self.reason,
            "failure": self.failure.value,
            "heel_point": None if self.heel_point is None else np.round(self.heel_point, 3).tolist(),
            "toe_point": None if self.toe_point is None else np.round(self.toe_point, 3).tolist(),
            "camera_to_table": None if self.camera_to_table is None else np.round(self.camera_to_table, 6).tolist(),
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
        }


MeasurementResult = SoleMeasurement | MeasurementRefused


def _round(value: float) -> float:
    return round(float(value), 3)


def check_glue_settings(glue_offset_mm: float, glue_spacing_mm: float) -> None:
    """ValueError unless the glue path's offset and spacing are possible (a tiny spacing would exhaust memory)."""
    (offset_low, offset_high), (spacing_low, spacing_high) = GLUE_OFFSET_RANGE_MM, GLUE_SPACING_RANGE_MM
    if not (offset_low <= glue_offset_mm <= offset_high and spacing_low <= glue_spacing_mm <= spacing_high):
        raise ValueError(
            f"glue offset must be in {offset_low:g}..{offset_high:g} mm and spacing in {spacing_low:g}..{spacing_high:g}"
            f" mm, got {glue_offset_mm:g} and {glue_spacing_mm:g}"
        )


def measure_sole(
    reconstruction: ReconstructionResult,
    glue_offset_mm: float = GLUE_OFFSET_MM,
    glue_spacing_mm: float = GLUE_SPACING_MM,
) -> MeasurementResult:
    """Length, heel and toe height and glue path of a reconstructed sole."""
    check_glue_settings(glue_offset_mm, glue_spacing_mm)
    timings = dict(reconstruction.timings)
    points = reconstruction.sole_points
    # What every result carries, valid or not; grows as the measurement learns more about the sole.
    base: dict[str, Any] = dict(points=len(points), timings=timings, camera_to_table=reconstruction.camera_to_table)
    if isinstance(reconstruction, ReconstructionRefused):
        return _invalid(reconstruction.failure, reconstruction.reason, **base)
    start = time.perf_counter()
    footprint = reconstruction.footprint
    smoothing = OUTLINE_SMOOTHING_MM if reconstruction.taught is not None else COLOUR_OUTLINE_SMOOTHING_MM
    outline = _smooth_closed(footprint.outline(), smoothing)
    centroid, axis = _principal_axis(outline)
    proj = (outline - centroid) @ axis
    lo, hi = float(proj.min()), float(proj.max())
    difference = _half_area_difference(footprint, centroid, axis, 0.5 * (lo + hi))
    if difference < 0:  # the toe is the end with the larger half: orient the axis heel -> toe
        axis, lo, hi, difference = -axis, -hi, -lo, -difference
    length = hi - lo
    base.update(axis=axis, outline=outline, half_area_difference=difference)
    if difference < MIN_HALF_AREA_DIFFERENCE:
        return _invalid(
            FailureKind.ENDS_TOO_CLOSE_TO_CALL,
            f"toe and heel too close to call: the footprint halves differ by {100 * difference:.1f} % of the area "
            f"(need {100 * MIN_HALF_AREA_DIFFERENCE:.0f} %)",
            **base,
        )
    surface = SoleSurface(reconstruction)  # one per reconstruction: its k-d tree serves every query below
    problem = _outline_problem(reconstruction, outline, surface)
    if problem is not None and reconstruction.unmeasured_fraction > MAX_UNMEASURED_FRACTION:
        # The outline lost part of the sole to pixels without depth: that is the reason, not the outline.
        return _invalid(
            FailureKind.SURFACE_NOT_MEASURED,
            f"{100 * reconstruction.unmeasured_fraction:.0f} % of the sole's pixels have no measured depth (glare "
            f"or no texture), so its edge cannot be confirmed ({problem.reason})",
            **base,
        )
    if problem is not None:
        return _invalid(problem.kind, problem.reason, **base)
    heel_xy = centroid + axis * (lo + HEIGHT_POINT_FRACTION * length)
    toe_xy = centroid + axis * (hi - HEIGHT_POINT_FRACTION * length)
    heights = surface.sample(np.vstack([heel_xy, toe_xy]), HEIGHT_RADIUS_MM)
    timings["measure"] = time.perf_counter() - start
    for name, value, xy in (("heel", heights.z[0], heel_xy), ("toe", heights.z[1], toe_xy)):
        if not np.isfinite(value):
            return _invalid(
                FailureKind.SURFACE_NOT_MEASURED,
                f"no measured surface at the {name} point ({xy[0]:.1f}, {xy[1]:.1f}) mm: fewer than "
                f"{MIN_CLOUD_POINTS} points within {HEIGHT_RADIUS_MM:g} mm",
                **base,
            )
    heel_z, toe_z = float(heights.z[0]), float(heights.z[1])
    heel_point, toe_point = np.array([*heel_xy, heel_z]), np.array([*toe_xy, toe_z])
    base.update(heel_point=heel_point, toe_point=toe_point)
    start = time.perf_counter()
    # The line glue_offset_mm inside the edge, from the footprint's distance transform: exact at pointed
    # and cusped ends too, where moving the outline along its normals would cross itself. Cell centres lie
    # half a cell inside the edge (Footprint.outline moves the contour back out by that half cell).
    # The offset is taken from the outline reported (smoothed against the edge's pixel noise), rasterised
    # again on the footprint's cells: the glue path keeps its distance from that outline.
    edge = footprint.filled(outline)
    inset = edge.eroded(glue_offset_mm + 0.5 * footprint.cell_mm).outline()
    if len(inset) < 3:
        return _invalid(
            FailureKind.MEASUREMENT_INVALID, f"no glue path: the sole is nowhere {glue_offset_mm:g} mm wide", **base
        )
    # Smoothing takes the raster's staircase out but pulls sharp corners in: back onto the offset line.
    glue_line = snap_to_inset(edge, _smooth_closed(inset, GLUE_OUTLINE_SMOOTHING_MM), glue_offset_mm)
    path, missing = glue_path(surface, glue_line, centroid, axis, 0.0, glue_spacing_mm)
    timings["glue_path"] = time.perf_counter() - start
    if path is None:
        return _invalid(FailureKind.SURFACE_NOT_MEASURED, missing or "no glue path", **base)
    problem = check_glue_coverage(
        np.isfinite(surface.coarse_heights(path.points[:, :2], _cover_radius(reconstruction)))
    )
    if problem is not None:
        return _invalid(problem.kind, problem.reason, **base)
    sole_z = np.quantile(points[:, 2], [0.01, 0.99])
    raw_z = path.points[:, 2] if path.raw_z is None else path.raw_z
    patch_normals = path.normals if path.surface_normals is None else path.surface_normals
    problem = check_glue_path(
        path.points, path.normals, raw_z, patch_normals, (float(sole_z[0]), float(sole_z[1])), glue_spacing_mm
    )
    if problem is not None:
        return _invalid(problem.kind, problem.reason, **base)
    implausible = _implausible(length, heel_z, toe_z)
    if implausible:
        return _invalid(FailureKind.MEASUREMENT_INVALID, implausible, **base)
    return SoleMeasurement(length_mm=length, heel_height_mm=heel_z, toe_height_mm=toe_z, glue_path=path, **base)


def _outline_problem(reconstruction: Reconstruction, outline: np.ndarray, surface: SoleSurface) -> CheckFailure | None:
    """The outline's self-checks: against the depth step, and against the right image when a table is taught."""
    ring = _resample_closed(outline, 1.0)
    outward = _outward_normals(ring)
    heights = _height_map(reconstruction)
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
    return check_outline_right(ring, outward, edge_height, changed_right, right_pixel, centre[:3], heights, table_level)


HEIGHT_MAP_CELL_MM = 1.0


def _height_map(reconstruction: Reconstruction) -> Callable[[np.ndarray], np.ndarray]:
    """Sole height at table points (NaN off the sole): the median of the sole's points per 1 mm cell."""
    points = reconstruction.sole_points
    raster = Footprint.empty_like(points[:, :2], HEIGHT_MAP_CELL_MM)
    row, col, _ = raster.cells(points[:, :2])
    flat = row * raster.mask.shape[1] + col
    order = np.lexsort((points[:, 2], flat))
    flat, z = flat[order], points[order, 2]
    starts = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]])
    counts = np.diff(np.r_[starts, len(flat)])
    grid = np.full(raster.mask.size, np.nan)
    grid[flat[starts]] = z[starts + counts // 2]  # the median of each cell's sorted heights

    def height(xy: np.ndarray) -> np.ndarray:
        r, c, inside = raster.cells(xy)
        return np.where(inside, grid[r * raster.mask.shape[1] + c], np.nan)

    return height


def _cover_radius(reconstruction: Reconstruction) -> float:
    """Radius holding MIN_CLOUD_POINTS where about half the pixels are measured (GLUE_COVER_RADIUS_MM at least):
    the same density of measurement asked of any rig, also one whose pixels cover more of the table."""
    calib, to_table = reconstruction.calibration, reconstruction.camera_to_table
    if calib is None or to_table is None:
        return GLUE_COVER_RADIUS_MM
    pixel_mm = abs(float(to_table[2, 3])) / calib.focal_px  # camera height above the table / focal length
    return max(GLUE_COVER_RADIUS_MM, float(np.sqrt(2.0 * MIN_CLOUD_POINTS / np.pi)) * pixel_mm)


def _implausible(length: float, heel_z: float, toe_z: float) -> str | None:
    """Why values outside what a sole can be are refused, or None: better no number than a wrong one."""
    low, high = PLAUSIBLE_LENGTH_MM
    if not low <= length <= high:
        return f"sole length {length:.1f} mm outside {low:g}..{high:g} mm"
    low, high = PLAUSIBLE_HEIGHT_MM
    for name, value in (("heel", heel_z), ("toe", toe_z)):
        if not low <= value <= high:
            return f"{name} height {value:.1f} mm outside {low:g}..{high:g} mm"
    return None


def _invalid(failure: FailureKind, reason: str, **fields_: Any) -> MeasurementRefused:
    return MeasurementRefused(failure, reason, **fields_)


def _principal_axis(outline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and unit principal axis (largest second moment) of the area inside a polygon."""
    moments = cv2.moments(outline.astype(np.float32))  # polygon moments by Green's theorem
    centroid = np.array([moments["m10"], moments["m01"]]) / moments["m00"]
    cov = np.array([[moments["mu20"], moments["mu11"]], [moments["mu11"], moments["mu02"]]])
    eigvals, eigvecs = np.linalg.eigh(cov)
    return centroid, eigvecs[:, int(np.argmax(eigvals))]


def _half_area_difference(footprint: Footprint, centroid: np.ndarray, axis: np.ndarray, middle: float) -> float:
    """(area beyond the middle along +axis - area before it) / total area, from the raster's cells."""
    proj = (footprint.centres() - centroid) @ axis
    upper = np.count_nonzero(proj > middle)
    return (2.0 * upper - len(proj)) / max(len(proj), 1)


def glue_path(
    surface: SoleSurface,
    outline: np.ndarray,
    centroid: np.ndarray,
    axis: np.ndarray,
    offset_mm: float = GLUE_OFFSET_MM,
    spacing_mm: float = GLUE_SPACING_MM,
) -> tuple[GluePath | None, str | None]:
    """The outline moved `offset_mm` inward, resampled every `spacing_mm`, lifted onto the top surface.

    Moving each point along the inward normal is exact for outlines whose curvature radius exceeds the
    offset everywhere, which holds for soles (the tightest curve, the toe, has a radius of several cm).
    Heights are sampled on the path and on a second ring GLUE_NORMAL_BASE_MM further in; the normal comes
    from a plane fitted to both around each point (a patch's own tilt is too noisy on a weakly textured
    sole: ~10 degrees).
    """
    resampled = _resample_closed(outline, 0.25)
    inward = -_outward_normals(resampled)
    path_xy = _resample_closed(resampled + offset_mm * inward, spacing_mm)
    start = int(np.argmin((path_xy - centroid) @ axis))  # the heel end
    path_xy = np.roll(path_xy, -start, axis=0)
    path_inward = -_outward_normals(path_xy)
    inner_xy = path_xy + GLUE_NORMAL_BASE_MM * path_inward
    samples = surface.sample(np.vstack([path_xy, inner_xy]), GLUE_FIT_RADIUS_MM)
    missing = np.flatnonzero(~np.isfinite(samples.z[: len(path_xy)]))
    if missing.size:
        x, y = path_xy[missing[0]]
        return None, (
            f"glue path: no top surface measured near ({x:.1f}, {y:.1f}) mm "
            f"({missing.size} of {len(path_xy)} path points)"
        )
    # Neighbouring patches overlap but their noise does not all average out; the surface is smooth, so a
    # plane fitted to the path's samples around each point takes the rest (cellctl.vision.local_fit: unbiased
    # for a sloping surface also where the path turns round a pointed end).
    sigma = GLUE_SMOOTHING_MM / spacing_mm
    raw = _without_single_outliers(samples.z[: len(path_xy)])
    z, _ = local_planes(path_xy, path_xy, raw, GLUE_SMOOTHING_MM)
    inner = _without_single_outliers(samples.z[len(path_xy) :])
    # The normal turns slowly along a sole's edge but slopes are differences of noisy heights: the plane for
    # it is fitted wider, over the path's samples and the ring GLUE_NORMAL_BASE_MM further in (the slope across).
    _, gradient = local_planes(
        path_xy, np.vstack([path_xy, inner_xy]), np.concatenate([raw, inner]), GLUE_NORMAL_SMOOTHING_MM
    )
    normals = np.column_stack([-gradient, np.ones(len(path_xy))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    patch_normals = _smooth_along(samples.normals[: len(path_xy)], sigma)
    patch_normals /= np.linalg.norm(patch_normals, axis=1, keepdims=True)
    return GluePath(np.column_stack([path_xy, z]), normals, True, raw, patch_normals), None


def _without_single_outliers(z: np.ndarray, limit_mm: float = GLUE_OUTLIER_MM) -> np.ndarray:
    """Heights along a closed path with isolated bad patch fits replaced by their neighbours' median.

    One patch fit can fail (a highlight, a mismatch) and smoothing would spread it over its neighbours;
    a lone value that departs from the median of the five around it is replaced. Two or more in a row are
    kept: that is the surface, or a fault the self-check must see (cellctl.vision.checks).
    """
    window = np.stack([np.roll(z, k) for k in (-2, -1, 0, 1, 2)])
    median = np.nanmedian(window, axis=0)
    bad = ~(np.abs(z - median) <= limit_mm)  # NaN counts as bad
    lone = bad & ~np.roll(bad, 1) & ~np.roll(bad, -1)
    return np.where(lone, median, z)


def _smooth_along(values: np.ndarray, sigma_samples: float) -> np.ndarray:
    """Gaussian smoothing of per-point values (N or N x k) along a closed path."""
    radius = min(int(np.ceil(3 * sigma_samples)), len(values) // 2)
    if radius < 1:
        return values
    kernel = cv2.getGaussianKernel(2 * radius + 1, sigma_samples).ravel()
    padded = np.concatenate([values[-radius:], values, values[:radius]])
    if padded.ndim == 1:
        return np.convolve(padded, kernel, mode="valid")
    return np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(padded.shape[1])])


def _resample_closed(poly: np.ndarray, spacing: float) -> np.ndarray:
    """Points every `spacing` mm of arc length along a closed polygon (first point kept, not repeated)."""
    ring = np.vstack([poly, poly[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))])
    count = max(3, int(round(arc[-1] / spacing)))
    s = np.linspace(0.0, arc[-1], count, endpoint=False)
    return np.column_stack([np.interp(s, arc, ring[:, 0]), np.interp(s, arc, ring[:, 1])])


def _smooth_closed(poly: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Gaussian smoothing along a closed polygon resampled at 0.25 mm (wrap-around at the ends)."""
    if len(poly) < 3:
        return poly
    step = 0.25
    ring = _resample_closed(poly, step)
    sigma = sigma_mm / step
    radius = int(np.ceil(3 * sigma))
    kernel = cv2.getGaussianKernel(2 * radius + 1, sigma).ravel()
    padded = np.vstack([ring[-radius:], ring, ring[:radius]])
    return np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(2)])


def _outward_normals(poly: np.ndarray) -> np.ndarray:
    """Unit outward normals of a counter-clockwise closed polygon."""
    tangent = np.roll(poly, -1, axis=0) - np.roll(poly, 1, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    return np.column_stack([tangent[:, 1], -tangent[:, 0]])
