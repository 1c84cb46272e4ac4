"""The edge-blur reading: sharp and soft steps told apart whatever their contrast, each camera on its own."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.vision.edge_blur import SOFT_EDGE_RATIO, edge_band, edge_blur_ratio, soft_edges


def _sole(blur_px: float, contrast: float, shift_px: int = 0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A bright ellipse on a darker textured table, drawn 8 x larger and shrunk (sub-pixel edges), blurred by
    `blur_px` with 1 DN of noise; and the ellipse's mask. `shift_px`: drawn that far to the left."""
    big = np.zeros((240 * 8, 320 * 8), np.float32)
    cv2.ellipse(big, ((160 - shift_px) * 8, 120 * 8), (100 * 8, 60 * 8), 15, 0, 360, 1.0, -1)
    mask = cv2.resize(big, (320, 240), interpolation=cv2.INTER_AREA) > 0.5
    rng = np.random.default_rng(seed)
    table = 40.0 + cv2.GaussianBlur(rng.normal(0.0, 6.0, (240, 320)).astype(np.float32), (0, 0), 2.0)
    image = table + contrast * cv2.resize(big, (320, 240), interpolation=cv2.INTER_AREA)
    image = cv2.GaussianBlur(image, (0, 0), blur_px) + rng.normal(0.0, 1.0, image.shape).astype(np.float32)
    return image, mask


@pytest.mark.parametrize("contrast", [30.0, 150.0])
def test_a_soft_edge_reads_above_the_limit_and_a_sharp_one_below(contrast: float) -> None:
    sharp, mask = _sole(0.5, contrast)
    soft, _ = _sole(1.4, contrast)
    assert edge_blur_ratio(sharp, edge_band(mask)) < SOFT_EDGE_RATIO < edge_blur_ratio(soft, edge_band(mask))
    assert soft_edges(soft, soft, mask, 0.0) and not soft_edges(sharp, sharp, mask, 0.0)


def test_each_camera_is_read_at_the_soles_place_in_its_own_image() -> None:
    """Each camera's image is read (the right one's band moved by the disparity): a soft right camera beside a sharp
    left one is found."""
    left, mask = _sole(0.5, 80.0)
    right_soft, _ = _sole(1.4, 80.0, shift_px=30, seed=1)
    right_sharp, _ = _sole(0.5, 80.0, shift_px=30, seed=1)
    assert soft_edges(left, right_soft, mask, 30.0)
    assert not soft_edges(left, right_sharp, mask, 30.0)


def test_no_band_reads_nothing() -> None:
    image, _ = _sole(0.5, 80.0)
    assert np.isnan(edge_blur_ratio(image, np.zeros(image.shape, bool)))
    assert not soft_edges(image, image, np.zeros(image.shape, bool), 0.0)


def test_a_defocused_simulated_pair_is_read_soft_and_a_sharp_one_not() -> None:
    """The simulator's cameras (the usual 0.5 px lens blur) are sharp; defocused by 1.2 px they are soft, and the
    reconstruction says so (its surface fits then leave the wider mixed band out)."""
    from dataclasses import replace

    from cellctl.sim.look import SceneLook
    from cellctl.sim.scene import SoleScene
    from cellctl.vision.reconstruction import SoleReconstructor
    from tests.sim_rig import half_size_rig

    calib = half_size_rig()
    reconstructor = SoleReconstructor(calib)
    sharp = SceneLook()
    for look, soft in ((sharp, False), (replace(sharp, left_defocus_px=1.2, right_defocus_px=1.2), True)):
        pair = SoleScene.random(1, "white", calib, look).render()
        reconstruction = reconstructor.reconstruct(pair.left, pair.right)
        assert reconstruction.valid and reconstruction.soft_edges is soft
