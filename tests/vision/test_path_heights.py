"""Glue path heights from noisy patch heights: a fit as wide as the local noise needs (cellctl.vision.surface)."""

from __future__ import annotations

import numpy as np

from cellctl.vision.local_fit import local_planes
from cellctl.vision.surface import (
    PATH_SMOOTHING_MAX_MM,
    PATH_SMOOTHING_MM,
    path_heights,
    path_noise,
    path_smoothing_widths,
)

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


def test_a_quiet_path_keeps_the_narrow_fit_exactly() -> None:
    """Light soles (patch scatter ~0.15 mm): the 6 mm fit as before, however curved the top (second
    differences do not see a smooth curve)."""
    xy = ellipse_path()
    z = top(xy) + correlated_noise(len(xy), 0.12, 1)
    assert np.all(path_smoothing_widths(z) == PATH_SMOOTHING_MM)
    np.testing.assert_allclose(path_heights(xy, z), local_planes(xy, xy, z, PATH_SMOOTHING_MM)[0], atol=1e-9)
    assert np.nanmax(path_noise(top(xy))) < 0.02


def test_a_noisy_stretch_is_fitted_wider_and_comes_closer_to_the_surface() -> None:
    """Black rubber (patch scatter 0.5 mm, correlated) on half the path: the fit widens there only, and the
    worst height error drops against the fixed narrow fit, over many noise draws."""
    xy = ellipse_path()
    truth = top(xy)
    noisy = np.arange(len(xy)) < len(xy) // 2
    worst_fixed, worst_adaptive = [], []
    for seed in range(20):
        z = truth + np.where(noisy, correlated_noise(len(xy), 0.5, seed), correlated_noise(len(xy), 0.1, seed))
        widths = path_smoothing_widths(z)
        assert np.median(widths[noisy][20:-20]) > 0.9 * PATH_SMOOTHING_MAX_MM
        assert np.all(widths[~noisy][20:-20] == PATH_SMOOTHING_MM)
        worst_fixed.append(np.max(np.abs(local_planes(xy, xy, z, PATH_SMOOTHING_MM)[0] - truth)[noisy]))
        worst_adaptive.append(np.max(np.abs(path_heights(xy, z) - truth)[noisy]))
    assert np.mean(worst_adaptive) < 0.8 * np.mean(worst_fixed)


def test_unknown_heights_are_left_out() -> None:
    xy = ellipse_path()
    z = top(xy) + correlated_noise(len(xy), 0.4, 3)
    z[40:44] = np.nan
    heights = path_heights(xy, z)
    assert np.all(np.isfinite(heights))
    assert np.max(np.abs(heights - top(xy))) < 1.0
