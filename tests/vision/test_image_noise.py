"""The sensor-noise estimate that gates a measurement (cellctl.vision.image_noise)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.images import grey_f32
from cellctl.vision.image_noise import MAX_IMAGE_NOISE_DN, exposure_noise_dn, image_noise_dn, mean_noise_dn


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


# ---- the noise averaging removes, read from a cycle's exposures ------------------------------------------------


@pytest.fixture(scope="module")
def rig():  # noqa: ANN201
    from cellctl.sim.rig import default_rig

    return default_rig()


def exposures(rig, noise_dn: float, count: int, textured: bool, seed: int = 0) -> list[np.ndarray]:  # noqa: ANN001
    """`count` raw BGR exposures of one still view: a flat grey, or a fine pattern of 2 x 2 pixel cells up to 8 DN
    apart (a patterned table's grain), each with its own sensor noise, rounded to 8 bits as a camera gives them."""
    width, height = rig.image_size
    rng = np.random.default_rng(seed)
    base = np.full((height, width, 3), 100.0)
    if textured:
        cells = rng.uniform(-4.0, 4.0, (height // 2 + 1, width // 2 + 1, 1))
        base += np.kron(cells, np.ones((2, 2, 3)))[:height, :width]
    noisy = (base + rng.normal(0.0, noise_dn, base.shape) for _ in range(count))
    return [np.clip(np.rint(image), 0, 255).astype(np.uint8) for image in noisy]


def read(rig, shots: list[np.ndarray]) -> float:  # noqa: ANN001
    from cellctl.vision.teach import average_exposures

    return exposure_noise_dn(shots[-1], average_exposures(shots))


def test_the_noise_averaging_removes_grows_with_the_sensors_noise(rig) -> None:  # noqa: ANN001
    clean, noisy = read(rig, exposures(rig, 1.0, 4, False)), read(rig, exposures(rig, 3.0, 4, False))
    assert noisy / clean == pytest.approx(3.0, rel=0.12)


def test_a_patterned_view_does_not_read_as_noise_between_exposures(rig) -> None:  # noqa: ANN001
    """The texture is the same in every exposure and cancels; read on one image, it adds to the noise."""
    flat, patterned = exposures(rig, 1.0, 4, False), exposures(rig, 1.0, 4, True)
    assert read(rig, patterned) == pytest.approx(read(rig, flat), rel=0.08)
    one = [grey_f32(rig.rectify(shots[-1], shots[-1])[0]) for shots in (flat, patterned)]
    assert image_noise_dn(one[1]) > 1.3 * image_noise_dn(one[0])


def test_what_averaging_removes_follows_the_number_of_exposures(rig) -> None:  # noqa: ANN001
    """sqrt(1 - 1/n) of one exposure's noise: 0 for one exposure, 0.71 at two, 0.87 at four."""
    four, two = read(rig, exposures(rig, 2.0, 4, True)), read(rig, exposures(rig, 2.0, 2, True))
    assert two / four == pytest.approx(np.sqrt(0.5 / 0.75), rel=0.08)
    assert read(rig, exposures(rig, 2.0, 1, True)) == 0.0


def test_the_noise_of_the_mean_follows_from_what_averaging_removed(rig) -> None:  # noqa: ANN001
    """sigma / sqrt(n) = removed / sqrt(n - 1): the mean of four exposures of a 2 DN camera holds half its noise."""
    from cellctl.vision.teach import average_exposures

    for count in (4, 8):
        shots = exposures(rig, 2.0, count, True)
        mean = average_exposures(shots)
        direct = float(np.std(mean.astype(np.float64) - exposures(rig, 0.0, 1, True)[0].astype(np.float64)))
        assert mean_noise_dn(exposure_noise_dn(shots[-1], mean), count) == pytest.approx(direct * 0.67, rel=0.15)
    with pytest.raises(ValueError, match="no noise"):
        mean_noise_dn(1.0, 1)
