"""Local plane fits along a glue path: a sloping surface round a pointed end keeps its height and slope."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellctl.vision.closed_path import smooth_along
from cellctl.vision.glue_path import sample_variance
from cellctl.vision.local_fit import disc_overlap, local_planes, slope_gradients
from cellctl.vision.surface import path_noise, sharp_turns


def test_a_rising_pointed_end_keeps_its_tip_height_and_slope() -> None:
    # A path round a 35 degree pointed end (tip at x = 0) on a surface rising 0.3 mm per mm towards the tip.
    s = np.linspace(-60.0, 60.0, 121)
    half = np.radians(17.5)
    xy = np.column_stack([-np.abs(s) * np.cos(half), s * np.sin(half)])
    z = 20.0 + 0.3 * xy[:, 0] + np.random.default_rng(0).normal(0.0, 0.05, len(s))
    height, gradient = local_planes(xy, xy, z, 6.0)
    tip = 60
    assert abs(height[tip] - 20.0) < 0.2  # the ridge shrinks the slope a little
    np.testing.assert_allclose(gradient[tip], [0.3, 0.0], atol=0.03)
    # Smoothing along the arc, as before, lowers the peak: what the plane fit is for.
    assert smooth_along(z, 6.0)[tip] < 19.0


def test_samples_on_one_line_give_the_lines_height_and_missing_samples_are_skipped() -> None:
    x = np.linspace(-20.0, 20.0, 41)
    xy = np.column_stack([x, np.zeros_like(x)])
    z = 5.0 + 0.1 * x
    z[20] = np.nan
    height, gradient = local_planes(np.array([[0.0, 0.0], [500.0, 0.0]]), xy, z, 4.0)
    assert abs(height[0] - 5.0) < 1e-6 and abs(gradient[0, 0] - 0.1) < 0.01 and gradient[0, 1] == 0.0
    assert np.isnan(height[1])


def _straight_path_with_ring(n: int = 120, spacing: float = 2.0, base: float = 15.0) -> tuple[np.ndarray, ...]:
    """A closed path's straight side: n points along x, a ring `base` mm inward (+y), unit tangents along x."""
    x = (np.arange(n) - n / 2) * spacing
    path = np.column_stack([x, np.zeros(n)])
    ring = path + [0.0, base]
    tangent = np.tile([1.0, 0.0], (n, 1))
    return path, ring, tangent


def _seat_into_ramp(xy: np.ndarray) -> np.ndarray:
    """A flat seat (x < 0) that turns into a ramp rising 0.3 mm per mm (x > 0), curving over 10 mm: the slope
    changes along the path within a 12 mm fit."""
    x = xy[:, 0]
    return 40.0 + np.where(x < 0.0, 0.0, np.where(x < 10.0, 0.3 * x * x / 20.0, 0.3 * (x - 5.0)))


def test_slope_change_along_the_path_is_followed_where_the_plane_would_take_up_the_ramp() -> None:
    path, ring, tangent = _straight_path_with_ring()
    xy = np.vstack([path, ring])
    z = _seat_into_ramp(xy) + np.random.default_rng(1).normal(0.0, 0.03, len(xy))
    variance = np.full(len(xy), 0.03**2)
    gradient, cubic = slope_gradients(path, tangent, xy, z, variance, 12.0, 2.0, 16.0)
    _, plane = local_planes(path, xy, z, 12.0)
    seat = np.flatnonzero((path[:, 0] > -8.0) & (path[:, 0] < -2.0))  # flat, 2-8 mm before the ramp starts
    assert np.all(plane[seat, 0] > 0.02)  # the plane takes up the ramp: > 1.1 degrees off
    assert np.max(np.abs(gradient[seat, 0])) < 0.7 * np.min(plane[seat, 0])  # measured 0.04 vs 0.055
    assert cubic[seat].all()


def test_a_slope_across_the_path_is_not_shrunk() -> None:
    # A top rising 0.45 mm per mm inward (24 degrees): the path and its ring 15 mm in fix the slope across, so
    # the fit's ridge must not pull it towards flat (GRADIENT_RIDGE_MM2 took 2 % off it: 0.441).
    path, ring, tangent = _straight_path_with_ring()
    xy = np.vstack([path, ring])
    z = 20.0 + 0.45 * xy[:, 1]
    gradient, _ = slope_gradients(path, tangent, xy, z, np.full(len(xy), 0.05**2), 12.0, 2.0, 16.0)
    middle = slice(20, -20)  # the open ends of this straight stretch have samples on one side only
    np.testing.assert_allclose(gradient[middle, 1], 0.45, rtol=0.005)
    np.testing.assert_allclose(gradient[middle, 0], 0.0, atol=1e-9)


def test_a_flat_seat_keeps_its_slope_just_before_the_top_starts_to_bend() -> None:
    # A flat seat whose top starts to curve down into the waist at x = 0 (z rising 0.012 x^2 beyond it, the
    # curvature jumping there): the cubic along the path, smooth through the jump, tilts the seat's normal a few mm
    # before it; the knee model is the top's own shape.
    path, ring, tangent = _straight_path_with_ring()
    xy = np.vstack([path, ring])
    z = 40.0 + 0.012 * np.clip(xy[:, 0], 0.0, None) ** 2 + np.random.default_rng(5).normal(0.0, 0.03, len(xy))
    gradient, cubic = slope_gradients(path, tangent, xy, z, np.full(len(xy), 0.03**2), 12.0, 2.0, 16.0)
    seat = np.flatnonzero((path[:, 0] > -7.0) & (path[:, 0] < -1.0))  # 2-6 mm before the bend
    assert cubic[seat].all()
    assert np.max(np.abs(gradient[seat, 0])) < 0.005  # measured 0.001; the cubic alone: 0.007-0.036
    bend = np.flatnonzero((path[:, 0] > 2.0) & (path[:, 0] < 10.0))
    np.testing.assert_allclose(gradient[bend, 0], 0.024 * path[bend, 0], atol=0.005)


def test_noise_alone_keeps_the_plane() -> None:
    path, ring, tangent = _straight_path_with_ring()
    xy = np.vstack([path, ring])
    rng = np.random.default_rng(2)
    errors, plane_errors, taken = [], [], []
    for _ in range(40):
        z = 10.0 + 0.05 * xy[:, 0] + rng.normal(0.0, 0.3, len(xy))  # a sloping plane, black rubber's noise
        gradient, cubic = slope_gradients(path, tangent, xy, z, np.full(len(xy), 0.3**2), 12.0, 2.0, 16.0)
        _, plane = local_planes(path, xy, z, 12.0)
        errors.append(np.abs(gradient[:, 0] - 0.05))
        plane_errors.append(np.abs(plane[:, 0] - 0.05))
        taken.append(cubic.mean())
    # The expected-error rule takes the cubic by chance at ~7 % of the points (measured 0.07 over these 40 paths),
    # and there its noise is larger: the 95th percentile of the slope errors is 1.6 x the plane's (the same before
    # and after SLOPE_RIDGE_MM2; 10 paths and their worst points, as this test read before, scatter 1.05-6.5 x).
    assert np.mean(taken) < 0.15
    assert np.quantile(np.concatenate(errors), 0.95) < 1.8 * np.quantile(np.concatenate(plane_errors), 0.95)


def test_no_cubic_where_the_path_folds_round_a_pointed_end() -> None:
    s = np.linspace(-60.0, 60.0, 61)
    half = np.radians(17.5)
    path = np.column_stack([-np.abs(s) * np.cos(half), s * np.sin(half)])
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    z = 20.0 + 0.3 * path[:, 0] + 0.01 * path[:, 0] ** 2
    _, cubic = slope_gradients(path, tangent, path, z, np.full(len(z), 0.01), 12.0, 2.0, 16.0)
    assert not cubic[20:41].any()  # within 2 widths of the tip


def _stadium_path(radius: float, length: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed path round two half circles of `radius` (centres (-25, 0) and (-25 - length, 0)) joined by straight
    sides, points `spacing` apart (counter-clockwise), and its unit inward normals."""
    arc = np.pi * radius
    s = np.arange(0.0, 2.0 * (arc + length), spacing)
    points, inward = [], []
    for t in s:
        if t < arc:  # the toe's half circle, from (-25, -radius) round the tip to (-25, radius)
            angle = -np.pi / 2 + t / radius
            centre = np.array([-25.0, 0.0])
        elif t < arc + length:  # the upper side, towards -x
            points.append([-25.0 - (t - arc), radius])
            inward.append([0.0, -1.0])
            continue
        elif t < 2.0 * arc + length:  # the heel's half circle
            angle = np.pi / 2 + (t - arc - length) / radius
            centre = np.array([-25.0 - length, 0.0])
        else:  # the lower side, back towards the toe
            points.append([-25.0 - length + (t - 2.0 * arc - length), -radius])
            inward.append([0.0, 1.0])
            continue
        outward = np.array([np.cos(angle), np.sin(angle)])
        points.append(centre + radius * outward)
        inward.append(-outward)
    return np.array(points), np.array(inward)


def test_a_toe_rising_to_its_tip_keeps_its_slope_where_the_path_turns_round_it() -> None:
    # A round toe (the path 23 mm round its cap's centre, the ring 15 mm further in) whose top rises to the tip and
    # curves up as a toe spring does: z = 20 + 0.37 x' + 0.008 x'^2 (x' = x + 2, 0 at the path's tip). At the tip
    # the slope is 0.37 (20 degrees); a plane through the path and the ring takes their mean slope, 0.25.
    path, inward = _stadium_path(23.0, 100.0, 2.0)
    ring = path + 15.0 * inward
    tangent = np.column_stack([inward[:, 1], -inward[:, 0]])
    xy = np.vstack([path, ring])
    ahead = xy[:, 0] + 2.0
    z = 20.0 + 0.37 * ahead + 0.008 * ahead**2 + np.random.default_rng(4).normal(0.0, 0.05, len(xy))
    gradient, _ = slope_gradients(path, tangent, xy, z, np.full(len(xy), 0.05**2), 12.0, 2.0, 16.0)
    tip = int(np.argmax(path[:, 0]))
    true = 0.37 + 2.0 * 0.008 * (path[tip, 0] + 2.0)
    np.testing.assert_allclose(gradient[tip], [true, 0.0], atol=0.02)  # 1 degree; the plane alone: 0.12 short
    _, plane = local_planes(path[tip : tip + 1], xy, z, 12.0)
    assert plane[0, 0] < true - 0.08


def test_disc_overlap() -> None:
    assert disc_overlap(0.0, 4.0) == 1.0 and disc_overlap(8.0, 4.0) == 0.0 and disc_overlap(20.0, 4.0) == 0.0
    values = disc_overlap(np.linspace(0.0, 8.0, 9), 4.0)
    assert np.all(np.diff(values) < 0.0)
    assert abs(disc_overlap(4.0, 4.0) - 0.391) < 0.001


def test_sample_variance_counts_the_patches_overlap() -> None:
    rng = np.random.default_rng(3)
    n = 400
    z = rng.normal(0.0, 0.2, n)
    # Samples further apart than two patch radii: independent, the path noise itself.
    # (A straight run closed on itself turns back at its ends: path_noise leaves out the second differences there.)
    far = np.column_stack([np.arange(n) * 10.0, np.zeros(n)])
    np.testing.assert_allclose(sample_variance(far, z, 10.0), path_noise(z, xy=far) ** 2)
    # 2 mm apart with 4 mm patches: the same heights read as more noise per sample (second differences miss
    # the shared part), counted with the correlated neighbours' sum (1 + 2 (0.69 + 0.39 + 0.14) = 3.44).
    near = np.column_stack([np.arange(n) * 2.0, np.zeros(n)])
    ratio = (sample_variance(near, z, 2.0) / path_noise(z, xy=near) ** 2)[10:-10]  # the open ends: fewer neighbours
    np.testing.assert_allclose(ratio, ratio[0])
    assert 6.5 < ratio[0] < 7.5  # 3.44 / (1 - 4/3 x 0.39)


def test_gradients_in_passes_over_the_samples_within_reach_are_those_over_all(monkeypatch) -> None:  # noqa: ANN001
    """slope_gradients works through the queries QUERY_CHUNK at a time, each pass over the samples within
    FIT_REACH_SIGMAS widths: the gradients of one pass over every sample to ~1e-7 and the same choices."""
    import cellctl.vision.local_fit as local_fit

    path, ring, tangent = _straight_path_with_ring()
    xy = np.vstack([path, ring])
    z = _seat_into_ramp(xy) + np.random.default_rng(3).normal(0.0, 0.2, len(xy))
    z[5] = np.nan
    variance = np.full(len(xy), 0.2**2)
    assert len(path) > 2 * local_fit.QUERY_CHUNK and len(path) % local_fit.QUERY_CHUNK
    # the path is longer than a pass's reach: the passes leave samples out
    assert np.ptp(path[:, 0]) > 2.0 * local_fit.FIT_REACH_SIGMAS * 12.0
    in_passes = slope_gradients(path, tangent, xy, z, variance, 12.0, 2.0, 16.0)
    monkeypatch.setattr(local_fit, "QUERY_CHUNK", len(path))
    monkeypatch.setattr(local_fit, "FIT_REACH_SIGMAS", np.inf)
    one_pass = slope_gradients(path, tangent, xy, z, variance, 12.0, 2.0, 16.0)
    np.testing.assert_allclose(in_passes[0], one_pass[0], rtol=0.0, atol=1e-6)
    np.testing.assert_array_equal(in_passes[1], one_pass[1])
    assert in_passes[1].any() and not in_passes[1].all()


def test_within_reach_keeps_every_sample_near_a_query() -> None:
    """within_reach: every sample within FIT_REACH_SIGMAS widths of a query is read, and far ones are not."""
    from cellctl.vision.local_fit import FIT_REACH_SIGMAS, within_reach

    rng = np.random.default_rng(4)
    at, xy = rng.uniform(0.0, 40.0, (32, 2)), rng.uniform(-300.0, 300.0, (5000, 2))
    distance = np.min(np.linalg.norm(xy[:, None] - at[None], axis=2), axis=1)
    chosen = np.zeros(len(xy), bool)
    chosen[within_reach(at, xy, 8.0)] = True
    assert np.all(chosen[distance <= FIT_REACH_SIGMAS * 8.0])
    assert not np.any(chosen[distance > FIT_REACH_SIGMAS * 8.0 * np.sqrt(2.0) + 60.0])  # the box grown


def _wobbly_closed_path(rng: np.random.Generator, n: int) -> np.ndarray:
    """Unit tangents of a random closed outline with lobes, pointed ends and jitter."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    radius = 1.0 + rng.uniform(0.2, 1.5) * sum(
        rng.uniform(0, 0.4) * np.cos(k * t + rng.uniform(0, 6)) for k in range(1, 6)
    )
    radius = np.abs(radius) + 0.1
    points = np.stack([radius * np.cos(t) * rng.uniform(50, 150), radius * np.sin(t) * 40], 1)
    points += rng.normal(0.0, rng.choice([0.0, 0.2, 2.0]), points.shape)
    tangent = np.roll(points, -1, axis=0) - np.roll(points, 1, axis=0)
    return tangent / np.linalg.norm(tangent, axis=1)[:, None]


def test_tip_and_fold_windows_are_their_pairwise_definitions() -> None:
    """round_a_tip (any two tangents within 2 sigma more than TIP_TURN_DEG apart) and unfolded (every tangent within
    FOLD_TURN_DEG of the point's own) read from unwrapped directions: the same as the pairwise dot products."""
    from cellctl.vision.local_fit import FOLD_TURN_DEG, TIP_TURN_DEG, round_a_tip, unfolded

    rng = np.random.default_rng(5)
    tips = folds = 0
    for _ in range(60):
        tangent = _wobbly_closed_path(rng, int(rng.integers(40, 400)))
        spacing, sigma = rng.uniform(0.5, 4.0), float(rng.choice([8.0, 12.0, 16.0]))
        reach = max(1, int(round(2.0 * sigma / spacing)))
        window = np.stack([np.roll(tangent, k, axis=0) for k in range(-reach, reach + 1)])
        pairwise = np.einsum("akd,bkd->kab", window, window).min(axis=(1, 2))
        centre = np.einsum("akd,kd->ka", window, tangent).min(axis=1)
        expected_tip = pairwise < np.cos(np.radians(TIP_TURN_DEG))
        expected_unfolded = centre > np.cos(np.radians(FOLD_TURN_DEG))
        np.testing.assert_array_equal(round_a_tip(tangent, sigma, spacing), expected_tip)
        np.testing.assert_array_equal(unfolded(tangent, sigma, spacing), expected_unfolded)
        tips, folds = tips + expected_tip.sum(), folds + (~expected_unfolded).sum()
    assert tips > 1000 and folds > 1000


def test_knee_sums_from_power_sums_are_the_direct_sums() -> None:
    """The knees' moments summed per interval between knots and accumulated (_knee_moments) against the B x K x M
    sums of the bend term itself."""
    from cellctl.vision.local_fit import _knee_knots, _knee_moments, _offsets

    rng = np.random.default_rng(6)
    at, xy = rng.uniform(-5.0, 5.0, (9, 2)), rng.uniform(-60.0, 60.0, (500, 2))
    xy[:20, 0] = np.round(xy[:20, 0])  # samples on knots
    tangent = np.tile([1.0, 0.0], (9, 1))
    z = rng.normal(0.0, 5.0, 500)
    seen = _offsets(at, xy, 12.0, tangent)
    dx, dy, w, u = seen
    knot, side = _knee_knots()
    sums, zsums = _knee_moments(seen, z, knot, side)
    bend = np.clip(side[:, None, None] * (u[None] - knot[:, None, None]), 0.0, None) ** 2
    direct = np.stack([np.sum(w * bend * t, axis=2) for t in (1.0, dx, dy, bend)], axis=2)
    scale = np.sum(w * (np.abs(u) + 12.0) ** 4, axis=1)[None, :, None]  # the terms' size before they cancel
    assert np.max(np.abs(sums - direct) / scale) < 1e-12
    assert np.max(np.abs(zsums - np.sum(w * bend * z, axis=2)) / scale[..., 0]) < 1e-12


def test_no_knee_fitted_to_the_noise_of_a_dished_black_top() -> None:
    # The glue normals' inputs recorded from a measured sole (data/dished_black_48110.npz: `dished-top`, black, seed
    # 48110 of the simulator; the path's and the ring's patch heights and their noise variances, as glue_path passes
    # them, and the true normals at the path). Along 10 mm the noise bent the measured heights enough that a knee fit
    # them at residual ratios of 0.73-0.79 of the cubic's, and with KNEE_RSS_RATIO at 0.8 it put a normal 5.2 degrees
    # off a smooth dish (the cubic there: 3.3-3.5; the plane: 1.7-2.3; before glue_path.across_bend, whose dish
    # correction these errors still include, 1-1.5 degrees of them). docs/sole-benchmark.md, thirty-seventh round.
    from cellctl.vision.glue_path import _slopes

    recorded = np.load(Path(__file__).parent / "data" / "dished_black_48110.npz")
    normals = _slopes(
        *(recorded[name] for name in ("path_xy", "path_inward", "inner_xy", "raw", "inner", "pv", "iv")),
        float(recorded["spacing"]),
    )
    error = np.degrees(np.arccos(np.clip(np.sum(normals * recorded["true_normals"], axis=1), -1.0, 1.0)))
    assert error.max() < 4.5, (int(np.argmax(error)), error.max())  # 3.49 (at 0.8: 5.19)


def test_the_noise_round_a_sprung_pointed_tip_is_the_heights_scatter_not_their_kink() -> None:
    # A pointed tip (a 35 degree wedge) whose top rises 0.5 mm per mm along the path to it: second differences
    # across the tip read the kink of the heights (~1.6 mm at the tip), not their noise (0.2 mm).
    spacing, half = 2.0, 60
    along = np.arange(-half, half + 1) * spacing  # signed distance along the path from the tip
    angle = np.radians(17.5)
    xy = np.column_stack([-np.abs(along) * np.cos(angle), along * np.sin(angle)])
    z = 30.0 - 0.5 * np.abs(along) + np.random.default_rng(4).normal(0.0, 0.2, len(along))
    tip = half
    assert sharp_turns(xy)[tip - 1 : tip + 2].all() and not sharp_turns(xy)[tip + 3 : -3].any()
    assert path_noise(z)[tip] > 0.4  # the kink read as noise: 0.51 (0.52 over 200 draws; 0.20 with the turn left out)
    assert 0.1 < path_noise(z, xy=xy)[tip] < 0.3
    # A round end (30 mm radius, 2 mm apart) turns ~15 degrees between the chords: nothing is left out.
    circle = 30.0 * np.column_stack([np.cos(np.arange(94) * 2.0 / 30.0), np.sin(np.arange(94) * 2.0 / 30.0)])
    assert not sharp_turns(circle).any()
