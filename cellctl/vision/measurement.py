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

The result types live in cellctl.vision.sole_result, the glue path's construction in cellctl.vision.glue_path,
the outline's self-checks on a reconstruction in cellctl.vision.outline_checks and the closed-path helpers in
cellctl.vision.closed_path; this module is the procedure whose steps refuse in order.
"""

from __future__ import annotations

import time
from concurrent import futures
from typing import Any

import cv2
import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.change import ALIKE_INSET_MM, MAX_TABLE_ALIKE_SHARE
from cellctl.vision.checks import (
    GLUE_COVER_RADIUS_MM,
    check_glue_coverage,
    check_glue_path,
    check_glue_precision,
    check_glue_rise,
    check_height_support,
    glue_deviation_limit,
)
from cellctl.vision.closed_path import smooth_closed
from cellctl.vision.defaults import (
    AVERAGED_FRAMES,
    GLUE_HEIGHT_TOLERANCE_MM,
    GLUE_HEIGHT_TOLERANCE_RANGE_MM,
    GLUE_OFFSET_MM,
    GLUE_OFFSET_RANGE_MM,
    GLUE_SPACING_MM,
    GLUE_SPACING_RANGE_MM,
    PLAUSIBLE_HEIGHT_MM,
    PLAUSIBLE_LENGTH_MM,
)
from cellctl.vision.edge_checks import MIN_CONCAVE_RADIUS_MM
from cellctl.vision.footprint import Footprint, snap_to_inset
from cellctl.vision.glue_path import depth_normals, glue_path
from cellctl.vision.image_edge import PlacedOutline, onto_image_edge
from cellctl.vision.image_noise import (
    CLEAN_EXPOSURE_NOISE_DN,
    CLEAN_IMAGE_NOISE_DN,
    MAX_IMAGE_NOISE_DN,
    NOISY_IMAGE_REMEDY,
    mean_noise_dn,
)
from cellctl.vision.outline_checks import outline_problem, wall_problem
from cellctl.vision.reconstruction import Reconstruction, ReconstructionRefused, ReconstructionResult
from cellctl.vision.sole_result import GluePath, MeasurementRefused, MeasurementResult, SoleMeasurement
from cellctl.vision.surface import MIN_CLOUD_POINTS, SoleSurface
from cellctl.vision.wall_draft import check_draft, check_glue_inset, foot_outline, wall_runs
from cellctl.vision.workers import worker

__all__ = [
    "GluePath",
    "MeasurementRefused",
    "MeasurementResult",
    "SoleMeasurement",
    "check_glue_settings",
    "measure_sole",
]

MAX_UNMEASURED_FRACTION = 0.05  # of the sole's changed pixels without depth: beyond, blame the lost pixels
HEIGHT_POINT_FRACTION = 0.10  # heights 10 % of the length in from each end
# The sole's own heights, for the glue path's range check (checks.check_glue_path): its points' 0.1st..99.9th
# percentiles. The toe of a short sole with a steep toe spring rises above its 99th percentile (a 213 mm simulated
# sole's top reaches 30.2 mm there, its 99th percentile 27.4), and the glue path runs round that toe; 0.1 % of a
# sole's ~10^5 points is still ~100 of them, so a few stray points do not widen the range.
SOLE_HEIGHT_QUANTILES = (0.001, 0.999)
HEIGHT_RADIUS_MM = 10.0  # patch for the heel and toe heights: on weak texture the noise falls with the radius
MIN_HALF_AREA_DIFFERENCE = 0.04  # toe and heel halves closer than this (fraction of area): too close to call
# Gaussian along the outline: removes the raster's staircase (0.25 mm cells) and pixel noise; wider would cut
# the tip of a pointed toe (a 2 mm sigma takes ~1 mm off a 35 degree wedge).
OUTLINE_SMOOTHING_MM = 0.75
# Without a taught table the edge comes from the colour test, whose noise on black soles biases the extreme
# projections (the length) outward by 0.3-0.5 mm at 0.75 mm: the 2 mm it was tuned with.
COLOUR_OUTLINE_SMOOTHING_MM = 2.0
# Radius of the disc the glue line's edge is closed with: a sole's outline curves inward nowhere tighter
# (edge_checks.MIN_CONCAVE_RADIUS_MM; simulated soles: 26 mm at least; a nozzle could not follow a tight notch
# either), while the measured outline has dents of 1-2 mm depth and 4-8 mm width where edge pixels lost their
# depth. A disc of radius R leaves R - sqrt(R^2 - w^2 / 4) of a dent w wide: 0.4 mm of a 6 mm dent at 12 mm.
GLUE_EDGE_CLOSE_MM = MIN_CONCAVE_RADIUS_MM
GLUE_OUTLINE_SMOOTHING_MM = 2.0  # the glue line's staircase and pixel noise; its inward normals follow it


def check_glue_settings(
    glue_offset_mm: float, glue_spacing_mm: float, glue_height_tolerance_mm: float = GLUE_HEIGHT_TOLERANCE_MM
) -> None:
    """ValueError unless the glue path's offset, spacing and height tolerance are possible (a tiny spacing would
    exhaust memory)."""
    (offset_low, offset_high), (spacing_low, spacing_high) = GLUE_OFFSET_RANGE_MM, GLUE_SPACING_RANGE_MM
    if not (offset_low <= glue_offset_mm <= offset_high and spacing_low <= glue_spacing_mm <= spacing_high):
        raise ValueError(
            f"glue offset must be in {offset_low:g}..{offset_high:g} mm and spacing in {spacing_low:g}..{spacing_high:g}"
            f" mm, got {glue_offset_mm:g} and {glue_spacing_mm:g}"
        )
    low, high = GLUE_HEIGHT_TOLERANCE_RANGE_MM
    if not low <= glue_height_tolerance_mm <= high:
        raise ValueError(f"glue height tolerance must be in {low:g}..{high:g} mm, got {glue_height_tolerance_mm:g}")


def _quieter_than_one_exposure(reconstruction: Reconstruction) -> bool:
    """Whether the surface was fitted on a mean quieter than one clean exposure (checks.glue_sd_limit). A clean
    camera's mean is. A noisy camera measured on the mean (`from_mean`) is not while the mean's own noise
    (image_noise.mean_noise_dn) is at least a clean exposure's: the regime the single-exposure share holds in.
    Averaged over more exposures (the noisy-camera remedy) it may become so: a sensor 2.5 times the simulator's
    over sixteen, not heavy noise (~1.15 DN)."""
    if not reconstruction.surface_averaged:
        return False
    if not reconstruction.from_mean:
        return True
    count = reconstruction.surface_exposures
    if count is None or count < 2:  # not said, or a mean this cycle did not make (replayed: its frame says 1)
        count = AVERAGED_FRAMES
    noise = reconstruction.exposure_noise_dn
    return noise is not None and mean_noise_dn(noise, count) < CLEAN_EXPOSURE_NOISE_DN


def measure_sole(
    reconstruction: ReconstructionResult,
    glue_offset_mm: float = GLUE_OFFSET_MM,
    glue_spacing_mm: float = GLUE_SPACING_MM,
    glue_height_tolerance_mm: float = GLUE_HEIGHT_TOLERANCE_MM,
    wall_draft_deg: float | None = None,
) -> MeasurementResult:
    """Length, heel and toe height and glue path of a reconstructed sole; a glue path whose heights are expected
    to stray beyond `glue_height_tolerance_mm` is refused (checks.check_glue_precision).

    wall_draft_deg: what the line knows of the sole model's side wall from its mould (a recipe says so). None:
    nothing, and a wall too low all round for the cell to see whether it leans out is refused
    (edge_checks.check_wall_height). 0: vertical, the outline found is the foot however low the wall. More: the
    wall leans out by that draft from the top edge to the table, hidden from the cameras; the outline, length and
    glue line are taken at its foot (cellctl.vision.wall_draft).
    """
    check_glue_settings(glue_offset_mm, glue_spacing_mm, glue_height_tolerance_mm)
    if wall_draft_deg:
        check_draft(wall_draft_deg)
    timings = dict(reconstruction.timings)
    points = reconstruction.sole_points
    # What every result carries, valid or not; grows as the measurement learns more about the sole.
    base: dict[str, Any] = dict(points=len(points), timings=timings, camera_to_table=reconstruction.camera_to_table)
    if isinstance(reconstruction, ReconstructionRefused):
        return _invalid(reconstruction.failure, reconstruction.reason, **base)
    start = time.perf_counter()
    footprint = reconstruction.footprint
    smoothing = OUTLINE_SMOOTHING_MM if reconstruction.taught is not None else COLOUR_OUTLINE_SMOOTHING_MM
    surface = SoleSurface(reconstruction)  # one per reconstruction: its neighbour grid serves every query below
    placed = onto_image_edge(reconstruction, smooth_closed(footprint.outline(), smoothing), surface)
    outline = placed.outline
    runs = wall_runs(outline, surface, wall_draft_deg) if wall_draft_deg else None
    if runs is not None:  # the checks below judge the top edge the cameras see; the rest is taken at the foot
        outline = foot_outline(outline, runs)
    # The glue line needs only the footprint and the outline: its rasters are drawn on a second thread from
    # here, beside the axis, the half areas, the outline checks and the heights (numpy, OpenCV and the C kernels
    # release the GIL); the glue path on it follows on the same thread once the axis is known. The refusals keep
    # their order: the glue path's come after the axis', the outline's and the heights'.
    line = worker("glue-path").submit(_glue_line, footprint, outline, glue_offset_mm)
    try:
        centroid, axis = _principal_axis(outline)
        proj = (outline - centroid) @ axis
        lo, hi = float(proj.min()), float(proj.max())
        difference = _half_area_difference(footprint, centroid, axis, 0.5 * (lo + hi))
        if difference < 0:  # the toe is the end with the larger half: orient the axis heel -> toe
            axis, lo, hi, difference = -axis, -hi, -lo, -difference
        length = hi - lo
        base.update(axis=axis, outline=outline, half_area_difference=difference)
        if difference < MIN_HALF_AREA_DIFFERENCE:
            return _refused_or_unmeasured(
                reconstruction,
                FailureKind.ENDS_TOO_CLOSE_TO_CALL,
                f"toe and heel too close to call: the footprint halves differ by {100 * difference:.1f} % of the "
                f"area (need {100 * MIN_HALF_AREA_DIFFERENCE:.0f} %)",
                base,
            )
        glue = worker("glue-path").submit(_glue, line, surface, centroid, axis, glue_spacing_mm)
        try:
            checked = _outline_and_heights(
                reconstruction, placed, surface, centroid, axis, lo, hi, base, wall_draft_deg is not None
            )
            timings["measure"] = time.perf_counter() - start
            if isinstance(checked, MeasurementRefused):
                return checked  # as before: whatever the glue path came to does not matter
            heel_z, toe_z = checked
            start = time.perf_counter()
            path, failure, missing = glue.result()
            timings["glue_path"] = time.perf_counter() - start  # what is left of it after the outline and heights
        finally:
            futures.wait([glue])  # never left running into the next cycle
    finally:
        futures.wait([line])
    if failure is not None:
        return _invalid(failure, missing or "no glue path", **base)
    assert path is not None
    if runs is not None and (problem := check_glue_inset(runs, glue_offset_mm)) is not None:
        return _invalid(problem.kind, problem.reason, **base)
    problem = check_glue_coverage(
        np.isfinite(surface.coarse_heights(path.points[:, :2], _cover_radius(reconstruction)))
    )
    if problem is not None:
        return _invalid(problem.kind, problem.reason, **base)
    sole_z = np.quantile(points[:, 2], SOLE_HEIGHT_QUANTILES)
    raw_z = path.points[:, 2] if path.raw_z is None else path.raw_z
    patch_normals = path.normals if path.surface_normals is None else path.surface_normals
    glue_xy = path.points[:, :2]
    problem = check_glue_path(
        path.points,
        path.normals,
        raw_z,
        patch_normals,
        (float(sole_z[0]), float(sole_z[1])),
        glue_spacing_mm,
        lambda index: depth_normals(surface, glue_xy, index, glue_spacing_mm),
        glue_deviation_limit(_depth_per_pixel_mm(reconstruction)),
    )
    if problem is None and path.edge_rise is not None:
        problem = check_glue_rise(path.edge_rise, glue_spacing_mm)
    if problem is None and path.height_sd is not None:
        problem = check_glue_precision(
            path.height_sd,
            glue_height_tolerance_mm,
            reconstruction.table_plane.obliqueness_deg(),
            quieter_than_one_exposure=_quieter_than_one_exposure(reconstruction),
            soft_edges=reconstruction.soft_edges,
            exposures=reconstruction.surface_exposures,
        )
    if problem is not None:
        return _invalid(problem.kind, problem.reason, more_exposures=problem.more_exposures, **base)
    implausible = _implausible(length, heel_z, toe_z)
    if implausible:
        return _invalid(FailureKind.MEASUREMENT_INVALID, implausible, **base)
    if reconstruction.unmeasured_fraction > MAX_UNMEASURED_FRACTION:
        # Last, so that a refusal the checks above name keeps its reason. Every valid result of the matrix sets
        # 16000 and 18000 lost at most 2 % of its pixels; a glossy sole that lost 12 % passed every check with its
        # heights 2-2.6 mm low (fresh set 19000, sole 19020): where that much is missing, what is left is not
        # trusted either.
        return _invalid(
            FailureKind.SURFACE_NOT_MEASURED,
            f"{100 * reconstruction.unmeasured_fraction:.0f} % of the sole's pixels have no measured depth "
            f"({_depth_holes_cause(reconstruction)}; at most {100 * MAX_UNMEASURED_FRACTION:.0f} %): "
            "what was measured between them is not trusted",
            **base,
        )
    return SoleMeasurement(length_mm=length, heel_height_mm=heel_z, toe_height_mm=toe_z, glue_path=path, **base)


def _refused_or_unmeasured(
    reconstruction: Reconstruction, failure: FailureKind, reason: str, base: dict[str, Any]
) -> MeasurementRefused:
    """A refusal of the footprint's shape (its outline's checks, its halves) for `reason`, or, where more than
    MAX_UNMEASURED_FRACTION of the sole's pixels have no depth, for those: the footprint lost part of the sole to
    them, and that is the reason, not its shape (a glossy toe without depth leaves halves 3 % apart: matrix sole
    3079, 35 % of its pixels without depth, refused as toe and heel too close to call). An outline refused where
    the sole looks like the table behind it (`table_alike_share` beyond MAX_TABLE_ALIKE_SHARE) is
    refused for the colours: the change masks that place its edge miss the sole in patches (cellctl.vision.change)."""
    if reconstruction.unmeasured_fraction > MAX_UNMEASURED_FRACTION:
        return _invalid(
            FailureKind.SURFACE_NOT_MEASURED,
            f"{100 * reconstruction.unmeasured_fraction:.0f} % of the sole's pixels have no measured depth "
            f"({_depth_holes_cause(reconstruction)}), so its edge cannot be confirmed "
            f"({reason})",
            **base,
        )
    alike = table_alike_share(reconstruction) if failure is FailureKind.OUTLINE_INCONSISTENT else None
    if alike is not None and alike > MAX_TABLE_ALIKE_SHARE:
        return _invalid(
            FailureKind.COLOURS_TOO_SIMILAR,
            f"the sole looks too much like the table for its edge to be found: {100 * alike:.0f} % of its pixels differ "
            f"from the taught table behind them by no more than the sensor's noise (a clear edge: under "
            f"{100 * MAX_TABLE_ALIKE_SHARE:.0f} %), so its outline cannot be confirmed ({reason}); use a table surface "
            "that contrasts with the sole",
            **base,
        )
    return _invalid(failure, reason, **base)


def table_alike_share(reconstruction: Reconstruction) -> float | None:
    """ChangeTest.alike_share over every 4th pixel of the sole's mask ALIKE_INSET_MM or more inside it (off its
    edge, whose pixels blend the sole and the table); None without a taught table. Read only for a refusal's words:
    an erosion of the whole image costs a few ms."""
    test, taught, mask = reconstruction.change_test, reconstruction.taught, reconstruction.sole_mask
    pixel_mm = reconstruction.pixel_mm
    if test is None or taught is None or mask is None or reconstruction.rectified is None or pixel_mm is None:
        return None
    reach = max(int(round(ALIKE_INSET_MM / pixel_mm)), 1)
    inner = cv2.erode(mask.view(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8))
    rows, cols = np.nonzero(inner)
    return test.alike_share(reconstruction.rectified[0], taught.left, np.column_stack([cols, rows])[::4])


def _depth_holes_cause(reconstruction: Reconstruction) -> str:
    """What leaves a sole's pixels without depth, with the image's noise where it was read: the simulator's normal
    sensor reads 0.5-0.75 DN, and a camera with three times its noise (under the image-noise check's
    limit, reads 1.2) left 21-22 % of black soles' pixels without depth (docs/sole-benchmark.md, sixteenth round).
    Measured on the mean of the cycle's exposures (the last one too noisy), more exposures lower that noise."""
    noise_dn = reconstruction.image_noise_dn
    if noise_dn is None:
        return "glare, no texture or image noise"
    where, remedy = "", ""
    if reconstruction.from_mean:
        where = " on the mean of the cycle's exposures (one alone is too noisy)"
        if noise_dn > CLEAN_IMAGE_NOISE_DN:
            remedy = f": {NOISY_IMAGE_REMEDY}"
    return (
        f"glare, no texture or image noise: the image's noise reads {noise_dn:.1f} DN{where}, refused beyond "
        f"{MAX_IMAGE_NOISE_DN:g}; a clean camera reads under {CLEAN_IMAGE_NOISE_DN:g}{remedy}"
    )


def _outline_and_heights(
    reconstruction: Reconstruction,
    placed: PlacedOutline,
    surface: SoleSurface,
    centroid: np.ndarray,
    axis: np.ndarray,
    lo: float,
    hi: float,
    base: dict[str, Any],
    wall_known: bool,
) -> tuple[float, float] | MeasurementRefused:
    """The wall's height (unless the sole model's wall is known from its mould), the outline's self-checks, then
    the heel and toe heights (added to `base`), or the refusal."""
    if not wall_known:
        # First, and not renamed for missing depth: a wall too low all round to show a lean cannot have its outline
        # confirmed, whatever the outline's checks find (on a flat sole they pass a leaning wall's outline).
        low = wall_problem(placed, surface)
        if low is not None:
            return _invalid(low.kind, low.reason, **base)
    problem = outline_problem(reconstruction, placed, surface)
    if problem is not None:
        return _refused_or_unmeasured(reconstruction, problem.kind, problem.reason, base)
    length = hi - lo
    heel_xy = centroid + axis * (lo + HEIGHT_POINT_FRACTION * length)
    toe_xy = centroid + axis * (hi - HEIGHT_POINT_FRACTION * length)
    heights = surface.sample(np.vstack([heel_xy, toe_xy]), HEIGHT_RADIUS_MM)
    for name, value, xy in (("heel", heights.z[0], heel_xy), ("toe", heights.z[1], toe_xy)):
        if not np.isfinite(value):
            return _invalid(
                FailureKind.SURFACE_NOT_MEASURED,
                f"no measured surface at the {name} point ({xy[0]:.1f}, {xy[1]:.1f}) mm: fewer than "
                f"{MIN_CLOUD_POINTS} points within {HEIGHT_RADIUS_MM:g} mm",
                **base,
            )
    heel_z, toe_z = float(heights.z[0]), float(heights.z[1])
    base.update(heel_point=np.array([*heel_xy, heel_z]), toe_point=np.array([*toe_xy, toe_z]))
    pixel_mm = reconstruction.pixel_mm
    if pixel_mm is not None:
        counts, _ = surface.grid.radius_medians(np.vstack([heel_xy, toe_xy]), HEIGHT_RADIUS_MM)
        sparse = check_height_support(("heel", "toe"), counts, np.pi * HEIGHT_RADIUS_MM**2 / pixel_mm**2)
        if sparse is not None:
            return _invalid(sparse.kind, sparse.reason, **base)
    return heel_z, toe_z


def _glue_line(
    footprint: Footprint, outline: np.ndarray, glue_offset_mm: float
) -> tuple[np.ndarray | None, str | None]:
    """The closed line `glue_offset_mm` inside the outline (table mm), or why there is none."""
    # The line glue_offset_mm inside the edge, from the footprint's distance transform: exact at pointed
    # and cusped ends too, where moving the outline along its normals would cross itself. Cell centres lie
    # half a cell inside the edge (Footprint.outline moves the contour back out by that half cell).
    # The offset is taken from the outline reported (smoothed against the edge's pixel noise), rasterised
    # again on the footprint's cells: the glue path keeps its distance from that outline.
    # A dent in the measured outline narrower than GLUE_EDGE_CLOSE_MM (edge pixels whose depth dropped out)
    # is no part of a sole's shape: the glue line does not follow it.
    edge = footprint.filled(outline).closed(GLUE_EDGE_CLOSE_MM)
    inset = edge.eroded(glue_offset_mm + 0.5 * footprint.cell_mm).outline()
    if len(inset) < 3:
        return None, f"no glue path: the sole is nowhere {glue_offset_mm:g} mm wide"
    # Smoothing takes the raster's staircase out but pulls sharp corners in: back onto the offset line.
    return snap_to_inset(edge, smooth_closed(inset, GLUE_OUTLINE_SMOOTHING_MM), glue_offset_mm), None


def _glue(
    line: futures.Future[tuple[np.ndarray | None, str | None]],
    surface: SoleSurface,
    centroid: np.ndarray,
    axis: np.ndarray,
    glue_spacing_mm: float,
) -> tuple[GluePath | None, FailureKind | None, str | None]:
    """The glue path on the glue line (`line`, drawn before on the same thread), or the failure kind and reason
    why there is none."""
    glue_line, no_line = line.result()
    if glue_line is None:
        return None, FailureKind.MEASUREMENT_INVALID, no_line
    path, missing = glue_path(surface, glue_line, centroid, axis, 0.0, glue_spacing_mm)
    return path, None if path is not None else FailureKind.SURFACE_NOT_MEASURED, missing


def _cover_radius(reconstruction: Reconstruction) -> float:
    """Radius holding MIN_CLOUD_POINTS where about half the pixels are measured (GLUE_COVER_RADIUS_MM at least):
    the same density of measurement asked of any rig, also one whose pixels cover more of the table."""
    pixel_mm = reconstruction.pixel_mm
    if pixel_mm is None:
        return GLUE_COVER_RADIUS_MM
    return max(GLUE_COVER_RADIUS_MM, float(np.sqrt(2.0 * MIN_CLOUD_POINTS / np.pi)) * pixel_mm)


def _depth_per_pixel_mm(reconstruction: Reconstruction) -> float | None:
    """The depth one disparity pixel spans at the table (mm): Z^2 / (f B), with Z = f x `Reconstruction.pixel_mm`;
    None without a stereo calibration."""
    pixel = reconstruction.pixel_mm
    if pixel is None or reconstruction.calibration is None:
        return None
    return pixel * pixel * reconstruction.calibration.focal_px / reconstruction.calibration.baseline_mm


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
    upper, total = footprint.cells_beyond(centroid, axis, middle)
    return (2.0 * upper - total) / max(total, 1)
