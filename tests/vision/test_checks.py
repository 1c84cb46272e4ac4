"""Self-checks of a measurement (cellctl.vision.checks): a wrong result is refused with its kind, a right one passes."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from cellctl.errors import FailureKind
from cellctl.vision import checks
from cellctl.vision.checks import (
    CALIBRATED_OBLIQUENESS_DEG,
    GLUE_DEVIATION_DEPTH_PX_MM,
    GLUE_MAX_DEVIATION_MM,
    GLUE_POINT_SD_SHARE,
    GLUE_TYPICAL_SD_SHARE,
    GLUE_TYPICAL_SD_SHARE_AVERAGED,
    check_glue_path,
    check_glue_precision,
    check_outline_depth,
    glue_deviation_limit,
    glue_sd_limit,
)
from cellctl.vision.footprint import Footprint
from cellctl.vision.glue_path import (
    GLUE_BEND_DEADBAND,
    GLUE_HEIGHT_RING_MM,
    GLUE_NORMAL_BASE_MM,
    across_bend,
    edge_rise,
    tilted,
    without_single_outliers,
)
from cellctl.vision.sole_region import depth_step
from cellctl.vision.table import TablePlane


def _ring(radius: float, count: int = 200) -> tuple[np.ndarray, np.ndarray]:
    angle = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    outward = np.column_stack([np.cos(angle), np.sin(angle)])
    return radius * outward, outward


def _upright(index: np.ndarray) -> np.ndarray:
    """The depth's normals at the glue points `index` of a flat top."""
    return np.tile([0.0, 0.0, 1.0], (len(index), 1))


def _glue(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    xy, _ = _ring(50.0, len(z))
    normals = np.tile([0.0, 0.0, 1.0], (len(z), 1))
    return np.column_stack([xy, z]), normals


def test_a_smooth_glue_path_on_the_sole_passes() -> None:
    z = 20.0 + np.sin(np.linspace(0, 2 * np.pi, 150, endpoint=False))
    points, normals = _glue(z)
    assert check_glue_path(points, normals, z + 0.3, normals, (15.0, 25.0), 2.0, _upright) is None


def test_a_glue_point_below_the_table_is_refused() -> None:
    z = np.full(150, 20.0)
    z[40:60] = -15.0 + np.abs(np.arange(20) - 10.0)  # what a 200 mm patch fit spread by smoothing looks like
    points, normals = _glue(z)
    problem = check_glue_path(points, normals, z, normals, (15.0, 25.0), 2.0, _upright)
    assert problem is not None and problem.kind is FailureKind.GLUE_PATH_INCONSISTENT
    assert "outside the sole's heights" in problem.reason


def test_a_height_jump_and_a_path_off_its_samples_are_refused() -> None:
    z = np.full(150, 20.0)
    z[70:] = 22.5
    points, normals = _glue(z)
    problem = check_glue_path(points, normals, z, normals, (15.0, 25.0), 2.0, _upright)
    assert problem is not None and "jumps" in problem.reason
    smooth = np.full(150, 20.0)
    raw = smooth.copy()
    raw[30] = 24.0
    points, normals = _glue(smooth)
    problem = check_glue_path(points, normals, raw, normals, (15.0, 25.0), 2.0, _upright)
    assert problem is not None and "from the surface measured there" in problem.reason


def test_glue_heights_too_coarse_for_the_tolerance_are_refused() -> None:
    """The median expected error along the path decides: a few coarser points (a pointed end's narrow fits) pass,
    a path coarse over most of its length does not, with the reason and the remedy."""
    sd = np.full(300, 0.75 * GLUE_TYPICAL_SD_SHARE)
    sd[:40] = GLUE_POINT_SD_SHARE - 0.01
    assert check_glue_precision(sd) is None
    sd[:] = GLUE_TYPICAL_SD_SHARE * 1.0 + 0.05
    sd[:100] = 0.5 * GLUE_TYPICAL_SD_SHARE
    problem = check_glue_precision(sd, 1.0)
    assert problem is not None and problem.kind is FailureKind.SURFACE_NOT_MEASURED
    assert (
        f"expected error is {GLUE_TYPICAL_SD_SHARE + 0.05:.2f} mm" in problem.reason
        and "1 mm tolerance" in problem.reason
    )
    assert "exposure" in problem.reason and "focus" in problem.reason and "glue_height_tolerance_mm" in problem.reason
    assert check_glue_precision(sd, 2.0) is None  # a cell whose dispenser allows 2 mm takes it
    unknown = check_glue_precision(np.full(10, np.nan))
    assert unknown is not None and unknown.kind is FailureKind.SURFACE_NOT_MEASURED


def test_the_glue_points_deviation_limit_grows_with_a_coarser_rigs_depth_pixel() -> None:
    """Set on the default rig (a disparity pixel 3.56-3.6 mm of depth at the table): unchanged there and where
    unknown, twice as large where a pixel spans twice the depth (the half-size rig)."""
    assert glue_deviation_limit(3.56) == glue_deviation_limit(None) == GLUE_MAX_DEVIATION_MM
    assert glue_deviation_limit(2 * GLUE_DEVIATION_DEPTH_PX_MM) == pytest.approx(2 * GLUE_MAX_DEVIATION_MM)
    points, normals = _glue(np.full(150, 20.0))
    raw = np.full(150, 20.0)
    raw[30:32] = 23.0  # two in a row: kept, 3 mm from the smoothed path
    assert check_glue_path(points, normals, raw, normals, (15.0, 25.0), 2.0, _upright) is not None
    limit = glue_deviation_limit(7.12)
    assert check_glue_path(points, normals, raw, normals, (15.0, 25.0), 2.0, _upright, limit) is None


def test_a_stretch_of_glue_heights_coarser_than_half_the_tolerance_is_refused_whatever_the_median() -> None:
    """A path fine in the median but with a stretch whose own expected error exceeds half the tolerance (sweep sole
    50010: 0.18 mm in the median, 0.61 at a bump published 1.15 mm off) is refused, naming the point and the count;
    a wider tolerance takes it."""
    sd = np.full(300, 0.5 * GLUE_TYPICAL_SD_SHARE)
    sd[40:52] = np.linspace(0.45, 0.61, 12)
    problem = check_glue_precision(sd, 1.0)
    assert problem is not None and problem.kind is FailureKind.SURFACE_NOT_MEASURED
    assert "at glue point 51" in problem.reason and "0.61 mm" in problem.reason
    assert "(8 points beyond 0.50, half the 1 mm tolerance" in problem.reason and "focus" in problem.reason
    assert check_glue_precision(sd, 1.25) is None
    soft = check_glue_precision(sd, 1.0, soft_edges=True)
    assert soft is not None and "soft at the sole's edge (a camera out of focus?)" in soft.reason
    assert "soft at the sole's edge" not in problem.reason
    sd[40:52] = GLUE_POINT_SD_SHARE - 0.001
    assert check_glue_precision(sd, 1.0) is None


def test_a_rig_looking_at_the_table_more_obliquely_than_calibrated_asks_for_finer_glue_heights() -> None:
    """Beyond CALIBRATED_OBLIQUENESS_DEG the worst glue points run further off their expected errors: the same path
    passes on a rig looking nearly straight down and is refused on a tilted one, with the tilt and the remedy."""
    sd = np.full(300, 0.9 * GLUE_TYPICAL_SD_SHARE)
    assert check_glue_precision(sd, 1.0, 2.5) is None
    assert check_glue_precision(sd, 1.0, CALIBRATED_OBLIQUENESS_DEG) is None
    problem = check_glue_precision(sd, 1.0, 9.7)
    assert problem is not None and problem.kind is FailureKind.SURFACE_NOT_MEASURED
    assert "9.7 degrees off its normal" in problem.reason and "square to the table" in problem.reason
    assert f"at most {glue_sd_limit(1.0, 9.7):.2f}" in problem.reason
    assert glue_sd_limit(1.0, 9.7) < 0.9 * GLUE_TYPICAL_SD_SHARE < glue_sd_limit(1.0, 0.0)
    assert glue_sd_limit(2.0, 0.0) == 2.0 * glue_sd_limit(1.0, 0.0)


def test_glue_heights_fitted_on_the_mean_of_exposures_are_held_to_a_smaller_expected_error() -> None:
    """On the mean the noise averages and the scene's own bias does not, so the worst point lies more expected errors
    out: an expected error one exposure may have is refused on the mean, and the refusal says it was the mean's."""
    assert GLUE_TYPICAL_SD_SHARE_AVERAGED < GLUE_TYPICAL_SD_SHARE
    sd = np.full(300, 0.5 * (GLUE_TYPICAL_SD_SHARE + GLUE_TYPICAL_SD_SHARE_AVERAGED))
    assert check_glue_precision(sd, 1.0) is None
    problem = check_glue_precision(sd, 1.0, quieter_than_one_exposure=True)
    assert problem is not None and problem.kind is FailureKind.SURFACE_NOT_MEASURED
    assert "on the mean of the exposures" in problem.reason
    assert f"at most {GLUE_TYPICAL_SD_SHARE_AVERAGED:.2f}" in problem.reason
    assert (
        glue_sd_limit(1.0, 9.7, quieter_than_one_exposure=True) < GLUE_TYPICAL_SD_SHARE_AVERAGED
    )  # oblique: smaller still
    assert (
        check_glue_precision(np.full(300, 0.9 * GLUE_TYPICAL_SD_SHARE_AVERAGED), 1.0, quieter_than_one_exposure=True)
        is None
    )


def test_on_a_mean_of_more_than_four_exposures_the_limit_tightens_as_measured() -> None:
    """Four exposures (the cycle's default) or fewer keep the mean's share; eight take it by the measured ratio of
    the multiples (2.86 / 3.19), sixteen by its square; one exposure's share is not touched. A refusal on four names
    eight exposures as a remedy with their limit; one on eight does not propose them again."""
    assert glue_sd_limit(1.0, 0.0, True, 4) == glue_sd_limit(1.0, 0.0, True, None) == GLUE_TYPICAL_SD_SHARE_AVERAGED
    assert glue_sd_limit(1.0, 0.0, True, 2) == GLUE_TYPICAL_SD_SHARE_AVERAGED
    assert glue_sd_limit(1.0, 0.0, True, 8) == pytest.approx(0.19 * 2.86 / 3.19)
    assert glue_sd_limit(1.0, 0.0, True, 16) == pytest.approx(0.19 * (2.86 / 3.19) ** 2)
    assert glue_sd_limit(1.0, 0.0, False, 8) == GLUE_TYPICAL_SD_SHARE
    sd = np.full(300, 0.18)
    assert check_glue_precision(sd, 1.0, quieter_than_one_exposure=True, exposures=4) is None
    on_eight = check_glue_precision(sd, 1.0, quieter_than_one_exposure=True, exposures=8)
    assert on_eight is not None and "at most 0.17 for the 1 mm tolerance" in on_eight.reason
    assert "averaged_frames" not in on_eight.reason
    on_four = check_glue_precision(np.full(300, 0.2), 1.0, quieter_than_one_exposure=True, exposures=4)
    assert on_four is not None
    assert "or average 8 exposures per cycle ([cameras] averaged_frames: at most 0.17 then" in on_four.reason
    on_one = check_glue_precision(np.full(300, 0.3), 1.0)  # one exposure: its share, no mean to average further
    assert on_one is not None and "averaged_frames" not in on_one.reason


def test_a_refusal_names_more_exposures_only_where_their_noise_averaging_can_bring_it_under_the_limit() -> None:
    """More exposures lower the error by at most the square root of their ratio (the sensor's noise; the scene's own
    error stays), so a cycle measures again on eight only where four's error, so lowered, meets eight's limit."""
    limit_on_eight = 0.19 * 2.86 / 3.19
    reachable = check_glue_precision(
        np.full(300, 0.99 * limit_on_eight * 2**0.5), 1.0, quieter_than_one_exposure=True, exposures=4
    )
    assert reachable is not None and reachable.more_exposures == 8 and "or average 8 exposures" in reachable.reason
    hopeless = check_glue_precision(
        np.full(300, 1.01 * limit_on_eight * 2**0.5), 1.0, quieter_than_one_exposure=True, exposures=4
    )
    assert hopeless is not None and hopeless.more_exposures is None and "averaged_frames" not in hopeless.reason
    unknown_count = check_glue_precision(
        np.full(300, 0.2), 1.0, quieter_than_one_exposure=True
    )  # a replayed mean: the cycle's four
    assert unknown_count is not None and unknown_count.more_exposures == 8
    for already, quieter in ((8, True), (16, True), (4, False)):  # on eight already; one exposure's share
        refused = check_glue_precision(np.full(300, 0.4), 1.0, quieter_than_one_exposure=quieter, exposures=already)
        assert refused is not None and refused.more_exposures is None
    tolerance_two = check_glue_precision(
        np.full(300, 0.4), 2.0, quieter_than_one_exposure=True, exposures=4
    )  # the limit scales with it
    assert tolerance_two is not None and tolerance_two.more_exposures == 8
    per_point = np.full(300, 0.05)
    per_point[7] = 0.9  # one point's own error: not the median's, no further exposures proposed
    refused_point = check_glue_precision(per_point, 1.0, quieter_than_one_exposure=True, exposures=4)
    assert refused_point is not None and refused_point.more_exposures is None


def test_a_table_planes_obliqueness_is_the_angle_of_its_normal_to_the_viewing_axis() -> None:
    assert TablePlane(np.array([0.0, 0.0, 1.0]), 500.0).obliqueness_deg() == 0.0
    tilt = np.radians(9.7)
    tilted = TablePlane(np.array([np.sin(tilt) * 0.6, np.sin(tilt) * 0.8, -np.cos(tilt)]), 500.0)
    assert abs(tilted.obliqueness_deg() - 9.7) < 1e-9


def _tilted(normals: np.ndarray, index: int | slice, degrees: float) -> np.ndarray:
    tilted = normals.copy()
    tilted[index] = [np.sin(np.radians(degrees)), 0.0, np.cos(np.radians(degrees))]
    return tilted


def test_a_glue_normal_against_the_surface_is_refused() -> None:
    """A glue normal 40 degrees from both the patches' normals and the depth's plane is refused, with both angles."""
    z = np.full(150, 20.0)
    points, normals = _glue(z)
    problem = check_glue_path(points, _tilted(normals, 10, 40.0), z, normals, (15.0, 25.0), 2.0, _upright)
    assert problem is not None and problem.kind is FailureKind.GLUE_PATH_INCONSISTENT
    assert "glue normal 10 is 40 degrees from the surface fitted around it and 40 from the depth's plane" in (
        problem.reason
    )


def test_patch_normals_a_colour_edge_tilted_do_not_refuse_a_glue_normal_the_depth_confirms() -> None:
    """The patches' normals tilted 50 degrees along a stretch (a rim's colour edge pulls their image fits) while
    the depth's plane agrees with the glue normals: not refused (the depth is asked along the whole path, once).
    Where the depth has no plane (NaN), the patches' word stands."""
    z = np.full(150, 20.0)
    points, normals = _glue(z)
    patches = _tilted(normals, slice(40, 46), 50.0)
    asked: list[np.ndarray] = []

    def depth(index: np.ndarray) -> np.ndarray:
        asked.append(index)
        return _upright(index)

    assert check_glue_path(points, normals, z, patches, (15.0, 25.0), 2.0, depth) is None
    assert len(asked) == 1
    np.testing.assert_array_equal(asked[0], np.arange(150))
    unknown = check_glue_path(points, normals, z, patches, (15.0, 25.0), 2.0, lambda i: np.full((len(i), 3), np.nan))
    assert unknown is not None and "50 degrees from the surface fitted around it and no depth there" in unknown.reason


def _leaning(count: int, degrees: float, index: slice | np.ndarray) -> np.ndarray:
    """Upright normals of a ring of glue points (`_glue`), those at `index` of a top rising towards the ring's outside
    (its edge) by `degrees` (negative: falling)."""
    _, outward = _ring(50.0, count)
    normals = np.tile([0.0, 0.0, 1.0], (count, 1))
    normals[index, :2] = -np.sin(np.radians(degrees)) * outward[index]
    normals[index, 2] = np.cos(np.radians(degrees))
    return normals


def test_a_top_rising_to_its_edge_under_level_glue_normals_is_refused() -> None:
    """A cupsole's lip: the patches' normals and the depth's planes both lean 20 degrees in (the top rises towards
    the edge) where the glue normals, taken over 15 mm, are level. Refused, all round or along a 100 mm stretch; a
    top falling to its edge as well; a narrow lip all round (the patches 8 degrees, the depth's wider planes 1.5)
    too. Either estimate alone, or both within their noise, is not refused."""
    z = np.full(150, 20.0)
    points, level = _glue(z)
    lip = _leaning(150, 20.0, slice(None))
    all_round = check_glue_path(points, level, z, lip, (15.0, 25.0), 2.0, lambda i: lip[i])
    assert all_round is not None and all_round.kind is FailureKind.GLUE_PATH_INCONSISTENT
    assert "rises towards its edge 20 degrees more steeply than the glue normals say along the whole path" in (
        all_round.reason
    )
    stretch = _leaning(150, 20.0, slice(60, 108))  # 100 mm of the 314 mm path
    heel_cup = check_glue_path(points, level, z, stretch, (15.0, 25.0), 2.0, lambda i: stretch[i])
    assert heel_cup is not None and "along 80 mm of it round glue point" in heel_cup.reason
    assert 60 <= int(heel_cup.reason.split("round glue point ")[1].split()[0]) < 108  # within the stretch
    falling = _leaning(150, -20.0, slice(None))
    fall = check_glue_path(points, level, z, falling, (15.0, 25.0), 2.0, lambda i: falling[i])
    assert fall is not None and "falls towards its edge" in fall.reason
    assert check_glue_path(points, level, z, lip, (15.0, 25.0), 2.0, _upright) is None  # the depth says level
    gentle, wide = _leaning(150, 8.0, slice(None)), _leaning(150, 1.5, slice(None))  # the depth's 6 mm averages it
    low_lip = check_glue_path(points, level, z, gentle, (15.0, 25.0), 2.0, lambda i: wide[i])
    assert low_lip is not None and "rises towards its edge 8 degrees" in low_lip.reason
    assert check_glue_path(points, level, z, gentle, (15.0, 25.0), 2.0, lambda i: level[i]) is None
    assert check_glue_path(points, lip, z, lip, (15.0, 25.0), 2.0, lambda i: lip[i]) is None  # normals follow it
    rng = np.random.default_rng(3)
    noisy = [_leaning(150, 1.0, slice(None)) for _ in range(2)]
    for normals in noisy:  # 10 degrees of noise on each estimate, both 1 degree off in the mean
        normals[:, :2] += rng.normal(0.0, 0.17, (150, 2))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    patches, depth = noisy
    assert check_glue_path(points, level, z, patches, (15.0, 25.0), 2.0, lambda i: depth[i]) is None
    assert checks.check_glue_tilt(points[:, :2], level, patches, np.full((150, 3), np.nan), 2.0) is None


def test_a_glue_line_standing_above_the_tops_course_over_a_stretch_is_refused() -> None:
    """A heel cup: the glue line's heights stand 1.5 mm above the line through the rings' heights further in over
    100 mm of the path (read at every other point, as the rings are sampled). Refused, naming it; the same
    0.8 mm all round, within what right soles read, passes."""
    rise = np.full(150, np.nan)
    rise[::2] = 0.1
    cup = rise.copy()
    cup[60:108:2] = 1.5
    problem = checks.check_glue_rise(cup, 2.0)
    assert problem is not None and problem.kind is FailureKind.GLUE_PATH_INCONSISTENT
    assert "the glue line stands 1.5 mm above the course of the sole's top further in along 80 mm" in problem.reason
    assert 60 <= int(problem.reason.split("round glue point ")[1].split()[0]) < 108
    assert checks.check_glue_rise(rise, 2.0) is None
    assert checks.check_glue_rise(np.where(np.isfinite(rise), 0.8, np.nan), 2.0) is None


def test_the_edge_rise_is_the_paths_height_over_the_rings_line() -> None:
    """edge_rise: 0 on a top sloping across the path, 90 c on a quadratic c t^2 across it (t mm in from the path:
    rings at 6 and 15 mm), the lip's height where the path alone is lifted; NaN between the rings' samples."""
    t = np.array([0.0, GLUE_HEIGHT_RING_MM, GLUE_NORMAL_BASE_MM])
    for top, expected in ((20.0 + 0.3 * t, 0.0), (20.0 - 0.01 * t**2, -0.9), (20.0 + np.array([2.0, 0, 0]), 2.0)):
        raw, ring, inner = np.full(6, top[0]), np.full(3, top[1]), np.full(6, top[2])
        rise = edge_rise(raw, ring, inner)
        np.testing.assert_allclose(rise[::2], expected, atol=1e-12)
        assert np.all(np.isnan(rise[1::2]))


def test_the_across_bend_is_the_median_rise_over_the_inner_ring_less_the_deadband() -> None:
    """glue_path.across_bend: a cup's rise of 0.18 mm all round is a slope of 0.03 the normals miss, less the
    deadband; a plain top's few hundredths of a mm are left alone, and so is a lip's rise (not a gentle curve)."""
    rise = np.full(200, np.nan)
    rise[::2] = np.random.default_rng(3).normal(0.18, 0.3, 100)
    rise[::2] += 0.18 - np.median(rise[::2])
    assert across_bend(rise) == pytest.approx(0.18 / GLUE_HEIGHT_RING_MM - GLUE_BEND_DEADBAND)
    assert across_bend(-rise) == pytest.approx(-across_bend(rise))
    assert across_bend(rise - 0.18 + 0.02) == 0.0
    assert across_bend(rise - 0.18 + 0.6) == 0.0
    assert across_bend(np.full(10, np.nan)) == 0.0
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    outward = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    turned = tilted(normals, outward, 0.05)
    np.testing.assert_allclose(-np.sum(turned[:, :2] * outward, axis=1) / turned[:, 2], 0.05)
    np.testing.assert_allclose(np.linalg.norm(turned, axis=1), 1.0)


def test_a_lone_failed_patch_fit_is_repaired_two_in_a_row_are_kept() -> None:
    z = np.full(50, 20.0)
    z[10] = 200.0
    z[30:32] = 40.0
    repaired = without_single_outliers(z)
    assert repaired[10] == 20.0 and np.all(repaired[30:32] == 40.0)


def _disc_footprint(radius: float) -> Footprint:
    cell = 0.25
    size = int(2 * (radius + 20) / cell)
    origin = (-(radius + 20), -(radius + 20))
    centres = (np.arange(size) + 0.5) * cell + origin[0]
    xx, yy = np.meshgrid(centres, centres)
    return Footprint((np.hypot(xx, yy) <= radius).astype(np.uint8), origin, cell)


def test_outline_on_the_depth_step_passes_one_inside_it_is_refused() -> None:
    raised = _disc_footprint(60.0)  # what the depth says, fattening of 3 mm included
    measured = _disc_footprint(75.0)
    outline, outward = _ring(57.0)  # the true edge
    assert check_outline_depth(outline, outward, raised, measured) is None
    inner, inner_out = _ring(49.0)  # a rim of 8 mm taken for table
    problem = check_outline_depth(inner, inner_out, raised, measured)
    assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT
    assert "still raised" in problem.reason


def _depth_step_with(extra: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> tuple[Footprint, Footprint]:
    """sole_region.depth_step: points measured everywhere within 75 mm, raised within 60 mm (the sole, 3 mm of
    fattening included) and where `extra(x, y)` says."""
    grid = _disc_footprint(75.0)
    centres = (np.arange(grid.mask.shape[0]) + 0.5) * grid.cell_mm + grid.origin[0]
    xx, yy = np.meshgrid(centres, centres)
    every = (np.hypot(xx, yy) <= 75.0).astype(np.float32)
    high = ((np.hypot(xx, yy) <= 60.0) | extra(xx, yy)).astype(np.float32)
    return depth_step(grid, every, high)


def test_a_speck_of_depth_apart_from_the_sole_is_no_evidence_a_part_joined_to_it_is(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    outline, outward = _ring(57.0, 358)  # the true edge, points 1 mm apart
    # A 9 x 1 mm streak of mismatched depth 7 mm beyond the edge (past an occlusion band): not sole, dropped.
    streak = lambda x, y: (np.abs(x) < 4.5) & (np.abs(y - 64.0) < 0.5)  # noqa: E731
    assert check_outline_depth(outline, outward, *_depth_step_with(streak)) is None
    monkeypatch.setattr(checks, "RAISED_SPECK_MM2", 0.0)  # kept, it is most of a 12 mm stretch raised 7 mm out
    problem = check_outline_depth(outline, outward, *_depth_step_with(streak))
    assert problem is not None and "stretch" in problem.reason
    monkeypatch.undo()
    # A part of the sole the outline left out (a 9 mm wide tongue to 70 mm) joins the sole, or lies near it (its
    # depth broken off 2 mm beyond the sole's, small as a speck): still refused.
    tongue = lambda x, y: (np.abs(x) < 4.5) & (y > 0) & (y < 70.0)  # noqa: E731
    broken = lambda x, y: (np.abs(x) < 4.5) & (y > 62.0) & (y < 66.0)  # noqa: E731
    for part in (tongue, broken):
        problem = check_outline_depth(outline, outward, *_depth_step_with(part))
        assert problem is not None and "stretch" in problem.reason


def test_untaught_the_outline_is_also_held_to_the_nearer_distance() -> None:
    """A 5 mm band the colour test read as table (a dark rim, a wall leaning out) is raised beyond the outline all
    round: inside the 7 mm fattening allowance, outside the untaught 3 mm one (8 px on the default rig)."""
    raised, measured = _disc_footprint(60.0), _disc_footprint(75.0)
    short, short_out = _ring(55.0)
    assert check_outline_depth(short, short_out, raised, measured) is None
    problem = check_outline_depth(short, short_out, raised, measured, outside_mm=3.0, supplementary=True)
    assert problem is not None and "still raised 3 mm outside" in problem.reason
    edge, edge_out = _ring(58.0)  # the edge with 2 mm of fattening beyond it passes at both distances
    assert check_outline_depth(edge, edge_out, raised, measured, outside_mm=3.0, supplementary=True) is None
    occluded = _disc_footprint(59.0)  # no depth 3 mm out (a tall wall hides the table): no evidence either way
    assert check_outline_depth(edge, edge_out, raised, occluded, outside_mm=3.0) is not None
    assert check_outline_depth(edge, edge_out, raised, occluded, outside_mm=3.0, supplementary=True) is None


def test_table_hidden_behind_a_tall_sole_does_not_count_against_its_outline() -> None:
    raised = _disc_footprint(60.0)
    outline, outward = _ring(57.0)
    # The camera sees no table beyond the half of the edge facing away from it: no depth there.
    measured = Footprint(_disc_footprint(75.0).mask.copy(), raised.origin, raised.cell_mm)
    centres = measured.centres()
    far = centres[(centres[:, 0] < 0) & (np.hypot(*centres.T) > 60.0)]
    row, col, _ = measured.cells(far)
    measured.mask[row, col] = 0
    assert check_outline_depth(outline, outward, raised, measured) is not None  # "not confirmed by depth"
    hidden = outline[:, 0] < 0
    assert check_outline_depth(outline, outward, raised, measured, hidden=hidden) is None
    # Hidden or not, an outline inside the edge still disagrees where the table is seen.
    inner, inner_out = _ring(49.0)
    assert check_outline_depth(inner, inner_out, raised, measured, hidden=inner[:, 0] < 0) is not None


def test_a_glue_path_over_unmeasured_surface_is_refused() -> None:
    from cellctl.vision.checks import MAX_GLUE_UNCOVERED, check_glue_coverage

    covered = np.ones(300, bool)
    covered[::50] = False  # isolated holes a patch bridges
    assert check_glue_coverage(covered) is None
    covered[100 : 100 + int(0.1 * 300)] = False  # a tenth of the path over a wall the cameras do not see
    problem = check_glue_coverage(covered)
    assert problem is not None and problem.kind is FailureKind.SURFACE_NOT_MEASURED
    assert 1.0 - covered.mean() > MAX_GLUE_UNCOVERED


def test_a_notch_cut_into_the_outline_is_refused_though_most_of_the_outline_agrees() -> None:
    raised = _disc_footprint(60.0)
    measured = _disc_footprint(75.0)
    outline, outward = _ring(57.0, 360)  # ~1 mm apart
    assert check_outline_depth(outline, outward, raised, measured) is None
    # 14 mm of the outline run 16 mm inside the sole (a part of it lost): 4 % of the outline.
    notched = outline.copy()
    notched[100:114] -= 16.0 * outward[100:114]
    problem = check_outline_depth(notched, outward, raised, measured)
    assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT
    assert "stretch" in problem.reason


def _hidden_step_by_step(
    table_points: np.ndarray,
    camera: np.ndarray,
    surface_height: Callable[[np.ndarray], np.ndarray],
    claimed: tuple[Footprint, np.ndarray] | None,
) -> np.ndarray:
    """checks._hidden's rule one height step at a time (as it was written before the steps were batched)."""
    hidden = np.zeros(len(table_points), bool)
    for z in np.arange(checks.HIDDEN_STEP_MM, checks.HIDDEN_MAX_MM, checks.HIDDEN_STEP_MM):
        xy = table_points[:, :2] + z / camera[2] * (camera[:2] - table_points[:, :2])
        height = surface_height(xy)
        hidden |= height >= z
        if claimed is not None:
            hidden |= np.isnan(height) & (claimed[1] >= z) & claimed[0].contains(xy)
    return hidden


def test_hidden_rays_are_the_step_by_step_rule() -> None:
    """A dome of a sole (NaN off it, and a hole without depth inside the claimed region), rays to a camera
    off to one side: every height step's verdict, batched, is the step-by-step one."""
    rng = np.random.default_rng(3)

    def dome(xy: np.ndarray) -> np.ndarray:
        r = np.hypot(xy[:, 0], xy[:, 1] / 0.4)
        z = np.where(r < 60.0, 25.0 * np.sqrt(np.clip(1.0 - (r / 60.0) ** 2, 0.0, None)), np.nan)
        return np.where(np.hypot(xy[:, 0] - 20.0, xy[:, 1]) < 6.0, np.nan, z)  # no depth in a hole

    claimed = Footprint.empty_like(np.array([[-70.0, -30.0], [70.0, 30.0]]), 0.5)
    claimed.mask[:] = 1
    points = np.column_stack([rng.uniform(-90, 90, 500), rng.uniform(-40, 40, 500), np.zeros(500)])
    camera = np.array([150.0, 20.0, 550.0])
    top = rng.uniform(0.0, 30.0, 500)
    for region in (None, (claimed, top)):
        expected = _hidden_step_by_step(points, camera, dome, region)
        assert 0 < np.count_nonzero(expected) < len(points)  # some rays pass, some do not
        np.testing.assert_array_equal(checks._hidden(points, camera, dome, region), expected)


def test_a_heel_height_resting_on_a_few_points_is_refused() -> None:
    # A fully measured patch holds about `expected` points; glare left the heel's with a tenth of them (19020).
    assert checks.check_height_support(("heel", "toe"), np.array([1900.0, 2300.0]), 2083.0) is None
    problem = checks.check_height_support(("heel", "toe"), np.array([237.0, 2327.0]), 2083.0)
    assert problem is not None and problem.kind is FailureKind.SURFACE_NOT_MEASURED
    assert "the heel height rests on 237 measured points where its patch holds about 2083 (11 %" in problem.reason
