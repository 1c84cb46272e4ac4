"""The sole surface's image fits give the same bits whether a large query runs on one thread or on two."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.sim.rig import default_rig
from cellctl.sim.scene import SoleScene
from cellctl.vision import surface
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.segmentation import Reconstruction
from cellctl.vision.surface import SoleSurface


def test_fits_split_over_two_threads_equal_the_serial_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    rig = default_rig()
    pair = SoleScene.random(2, "white", rig).render()
    reconstruction = SoleReconstructor(rig).reconstruct(pair.left, pair.right)
    assert isinstance(reconstruction, Reconstruction), reconstruction.reason
    points = reconstruction.sole_points
    # Queries over the sole and a few beyond it (cloud fallbacks and unmeasured ones are split too).
    rng = np.random.default_rng(0)
    low, high = points[:, :2].min(axis=0) - 20.0, points[:, :2].max(axis=0) + 20.0
    xy = rng.uniform(low, high, (300, 2))
    assert len(xy) >= surface.PARALLEL_MIN_FITS
    split = SoleSurface(reconstruction).sample(xy, 4.0)
    monkeypatch.setattr(surface, "PARALLEL_MIN_FITS", len(xy) + 1)
    serial = SoleSurface(reconstruction).sample(xy, 4.0)
    assert np.count_nonzero(serial.refined) > 100  # most queries fitted on the images, the split has work
    assert np.any(~serial.refined)
    np.testing.assert_array_equal(split.refined, serial.refined)
    np.testing.assert_array_equal(split.z, serial.z)
    np.testing.assert_array_equal(split.normals, serial.normals)
