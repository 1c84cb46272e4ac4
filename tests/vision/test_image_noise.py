"""The sensor-noise estimate that gates a measurement (cellctl.vision.image_noise)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.image_noise import MAX_IMAGE_NOISE_DN, image_noise_dn


def scene(noise_dn: float, seed: int = 0) -> np.ndarray:
    """A grey image with a brightness ramp, a bright sole-like block and texture lines, plus white noise."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:512, 0:640].astype(np.float32)
    image = 40.0 + 0.05 * xs + 0.03 * ys
    image[150:350, 200:500] += 120.0  # strong edges: a few per cent of the pixels
    image[::40, :] += 30.0  # grid lines of a cutting mat
    return (image + rng.normal(0.0, noise_dn, image.shape)).astype(np.float32)


@pytest.mark.parametrize("noise", [0.5, 1.0, 2.0, 4.0])
def test_the_noise_of_an_image_with_edges_and_lines_is_found(noise: float) -> None:
    assert image_noise_dn(scene(noise)) == pytest.approx(noise, rel=0.15)


def test_the_gate_lies_between_a_normal_and_a_noisy_sensor() -> None:
    assert image_noise_dn(scene(0.7)) < MAX_IMAGE_NOISE_DN < image_noise_dn(scene(2.2))
