"""Glue path heights from noisy patch heights: per point the local fit (width, plane or plane plus the curve along
the path) of smallest expected error (cellctl.vision.surface.path_heights)."""

from __future__ import annotations

import numpy as np

from cellctl.vision.glue_path import (
    GLUE_HEIGHT_RING_MM,
    GLUE_NORMAL_BASE_MM,
    GLUE_RING_STRIDE,
    GLUE_SLOPE_NOISE_RATIO,
    sample_variance,
)
from cellctl.vision.local_fit import local_planes
from cellctl.vision.surface import PATH_SMOOTHING_MM, PATH_SMOOTHING_STEPS_MM, height_rows, path_heights

SPACING = 2.0  # mm, the glue path's default


def ellipse_path(n: int = 300) -> np.ndarray:
    """A sole-sized closed path, samples about SPACING mm apart."""
    angle = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([130.0 * np.cos(angle), 45.0 * np.sin(angle)])


def top(xy: np.ndarray) -> np.ndarray:
    """A curved, sloping top: 15 mm at the middle, rising to the toe, falling off across."""
    return 15.0 + 0.02 * xy[:, 0] + 0.00012 * xy[:, 0] ** 2 - 0.0006 * xy[:, 1] ** 2


def correlated_noise(n: int, sd: float, seed: int, length: int = 1) -> np.ndarray:
    """Noise correlated over ~`length` samples (overlapping patches, the matcher's noise on black rubber)."""
    white = np.random.default_rng(seed).normal(size=n + 2 * length)
    kernel = np.ones(2 * length + 1)
    smooth = np.convolve(white, kernel, mode="same")[length : length + n]
    return sd * smooth / smooth.std()


def heights(xy: np.ndarray, z: np.ndarray) -> np.ndarray:
    """path_heights with the noise model glue_path gives it."""
    return path_heights(xy, z, GLUE_SLOPE_NOISE_RATIO**2 * sample_variance(xy, z, SPACING))[0]


def test_the_expected_error_follows_the_noise() -> None:
    """The heights' expected error (the chosen fit's noise and bias, as an sd) grows with the patches' noise, and
    the heights' actual errors are of its size: the glue-precision check reads it (checks.check_glue_precision)."""
    xy = ellipse_path()
    typical = []
    for sd in (0.15, 0.3, 0.6):
        errors, expected = [], []
        for seed in range(4):
            z = top(xy) + correlated_noise(len(xy), sd, seed, 2)
            result, error = path_heights(xy, z, GLUE_SLOPE_NOISE_RATIO**2 * sample_variance(xy, z, SPACING))
            assert np.all(np.isfinite(error)) and np.all(error > 0)
            errors.append(np.sqrt(np.mean((result - top(xy)) ** 2)))
            expected.append(np.median(error))
        typical.append(np.median(expected))
        # the model's noise is taken at its tail (GLUE_SLOPE_NOISE_RATIO): never below the actual error
        assert 1.0 < np.median(expected) / np.median(errors) < 3.0
    assert typical[0] < typical[1] < typical[2]
    np.testing.assert_allclose(typical[2] / typical[0], 4.0, rtol=0.35)


def test_the_plane_rows_are_local_planes() -> None:
    xy = ellipse_path()
    z = top(xy) + correlated_noise(len(xy), 0.3, 4)
    for width in PATH_SMOOTHING_STEPS_MM:
        np.testing.assert_allclose(height_rows(xy, xy, width) @ z, local_planes(xy, xy, z, width)[0], atol=1e-9)


def test_the_curved_fit_follows_a_curve_along_the_path_exactly() -> None:
    """On a straight path a height quadratic in the distance along it is fitted exactly by the curved rows (the
    plane of the same width bends it by ~ curvature x width^2 / 2)."""
    xy = np.column_stack([np.arange(-150.0, 150.0, SPACING), np.full(150, 5.0)])
    z = 10.0 + 0.01 * xy[:, 0] ** 2
    tangent = np.tile([1.0, 0.0], (len(xy), 1))
    inner = slice(30, -30)
    curved = height_rows(xy, xy, 12.0, tangent) @ z
    np.testing.assert_allclose(curved[inner], z[inner], atol=1e-6)
    assert np.min(np.abs(height_rows(xy, xy, 12.0) @ z - z)[inner]) > 1.0


def test_a_quiet_curved_path_is_not_bent() -> None:
    """Light soles (patch scatter ~0.12 mm) on a curved top: no worse than the narrow plane, over noise draws."""
    xy = ellipse_path()
    truth = top(xy)
    worst_narrow, worst_chosen = [], []
    for seed in range(10):
        z = truth + correlated_noise(len(xy), 0.12, seed)
        worst_narrow.append(np.max(np.abs(local_planes(xy, xy, z, PATH_SMOOTHING_MM)[0] - truth)))
        worst_chosen.append(np.max(np.abs(heights(xy, z) - truth)))
    assert np.mean(worst_chosen) < np.mean(worst_narrow)


def test_a_noisy_stretch_comes_closer_to_the_surface_than_the_narrow_plane() -> None:
    """Black rubber (patch scatter 0.5 mm, correlated) on half the path: the worst height error there drops
    against the narrow plane, over many noise draws."""
    xy = ellipse_path()
    truth = top(xy)
    noisy = np.arange(len(xy)) < len(xy) // 2
    worst_fixed, worst_chosen = [], []
    for seed in range(20):
        z = truth + np.where(noisy, correlated_noise(len(xy), 0.5, seed), correlated_noise(len(xy), 0.1, seed))
        worst_fixed.append(np.max(np.abs(local_planes(xy, xy, z, PATH_SMOOTHING_MM)[0] - truth)[noisy]))
        worst_chosen.append(np.max(np.abs(heights(xy, z) - truth)[noisy]))
    assert np.mean(worst_chosen) < 0.8 * np.mean(worst_fixed)


def test_a_noisy_curved_top_comes_closer_than_the_wide_plane() -> None:
    """Black rubber (0.35 mm) on a top that bends along the path (a waist: 3 mm down over ~20 mm): the wide plane
    that the noise alone would ask for bends it; the chosen fits come closer, over noise draws."""
    xy = ellipse_path()
    waist = 3.0 * np.exp(-0.5 * ((xy[:, 0] - 20.0) / 10.0) ** 2) * (xy[:, 1] > 0)
    truth = top(xy) - waist
    worst_wide, worst_chosen = [], []
    for seed in range(10):
        z = truth + correlated_noise(len(xy), 0.35, seed)
        worst_wide.append(np.max(np.abs(local_planes(xy, xy, z, PATH_SMOOTHING_STEPS_MM[-1])[0] - truth)))
        worst_chosen.append(np.max(np.abs(heights(xy, z) - truth)))
    assert np.mean(worst_chosen) < 0.8 * np.mean(worst_wide)


def test_unknown_heights_are_left_out() -> None:
    xy = ellipse_path()
    z = top(xy) + correlated_noise(len(xy), 0.4, 3)
    z[40:44] = np.nan
    result = heights(xy, z)
    assert np.all(np.isfinite(result))
    assert np.max(np.abs(result - top(xy))) < 1.0


def test_heights_in_passes_over_the_samples_within_reach_are_those_over_all(monkeypatch) -> None:  # noqa: ANN001
    """path_heights works through the queries QUERY_CHUNK at a time (arrays that stay in the cache), each pass over
    the samples within local_fit.FIT_REACH_SIGMAS widths: the heights of one pass over every sample to ~1e-8 mm."""
    import cellctl.vision.local_fit as local_fit

    xy = ellipse_path(301)  # not a multiple of the pass size
    z = top(xy) + correlated_noise(len(xy), 0.3, 5, 2)
    z[[7, 150]] = np.nan
    ring_xy = _rings(xy)
    ring_z = top(ring_xy) + correlated_noise(len(ring_xy), 0.3, 6, 2)
    in_passes = heights(xy, z), _with_rings(xy, z, ring_xy, ring_z)
    assert len(xy) > 2 * local_fit.QUERY_CHUNK
    assert np.ptp(xy[:, 0]) > 2.0 * local_fit.FIT_REACH_SIGMAS * PATH_SMOOTHING_STEPS_MM[-1]  # some are left out
    monkeypatch.setattr(local_fit, "QUERY_CHUNK", len(xy))
    monkeypatch.setattr(local_fit, "FIT_REACH_SIGMAS", np.inf)
    for passes, one_pass in zip(in_passes, (heights(xy, z), _with_rings(xy, z, ring_xy, ring_z)), strict=True):
        np.testing.assert_allclose(passes, one_pass, rtol=0.0, atol=1e-6)


def _rings(xy: np.ndarray) -> np.ndarray:
    """The rings glue_path samples for the heights: the normals' ring at each point, then the heights' own ring at
    every GLUE_RING_STRIDE-th."""
    from cellctl.vision.closed_path import outward_normals

    inward = -outward_normals(xy)
    return np.vstack([xy + GLUE_NORMAL_BASE_MM * inward, (xy + GLUE_HEIGHT_RING_MM * inward)[::GLUE_RING_STRIDE]])


def _with_rings(xy: np.ndarray, z: np.ndarray, ring_xy: np.ndarray, ring_z: np.ndarray) -> np.ndarray:
    """path_heights with the rings' samples (_rings), with the noise model glue_path gives them."""
    from cellctl.vision.surface import RingSamples

    ratio = GLUE_SLOPE_NOISE_RATIO**2
    n = len(xy)
    variance = np.concatenate(
        [
            sample_variance(ring_xy[:n], ring_z[:n], SPACING),
            sample_variance(ring_xy[n:], ring_z[n:], GLUE_RING_STRIDE * SPACING),
        ]
    )
    return path_heights(xy, z, ratio * sample_variance(xy, z, SPACING), RingSamples(ring_xy, ring_z, ratio * variance))[
        0
    ]


def test_rings_further_in_average_the_edge_patches_noise() -> None:
    """Black rubber: the glue points' patches (2 mm from the edge) scatter 0.5 mm, those further in 0.33,
    independently. Planes across the path and the rings come closer to the surface than the path's own fits,
    over noise draws (a plane through the path and one ring alone would pass through the path's own mean). The
    gain is modest here, the path's noise being correlated over 10 mm (16 simulated black soles: the worst glue
    point's mean 0.68 -> 0.59 mm, /work/notes/s15/exp7-ctl.txt)."""
    xy = ellipse_path()
    ring_xy = _rings(xy)
    truth = top(xy)
    rms_path, rms_rings = [], []
    for seed in range(10):
        z = truth + correlated_noise(len(xy), 0.5, seed, 2)
        ring_z = top(ring_xy) + correlated_noise(len(ring_xy), 0.33, 100 + seed, 1)
        rms_path.append(np.sqrt(np.mean((heights(xy, z) - truth) ** 2)))
        rms_rings.append(np.sqrt(np.mean((_with_rings(xy, z, ring_xy, ring_z) - truth) ** 2)))
    assert np.mean(rms_rings) < 0.94 * np.mean(rms_path)


def test_a_top_falling_towards_the_path_is_not_lifted_by_the_rings() -> None:
    """A rounded top edge: the surface under the glue path lies 0.8 mm below the plane through the rings further
    in. The planes across them would lift the path towards the rings; their bias against the path's own fit rules
    them out, so the heights stay those of the path's surface."""
    xy = ellipse_path()
    ring_xy = _rings(xy)
    truth = top(xy) - 0.8
    for seed in range(4):
        z = truth + correlated_noise(len(xy), 0.15, seed, 2)
        ring_z = top(ring_xy) + correlated_noise(len(ring_xy), 0.1, 100 + seed, 1)
        errors = _with_rings(xy, z, ring_xy, ring_z) - truth
        assert abs(np.mean(errors)) < 0.1 and np.max(np.abs(errors)) < 0.4
