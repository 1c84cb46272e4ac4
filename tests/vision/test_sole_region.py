"""The sole region's helpers against what they replace."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.sole_region import disc_closing


def test_disc_closing_is_opencvs_closing_with_its_disc() -> None:
    rng = np.random.default_rng(5)
    for size in (1, 3, 9, 31, 61):
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        for shape in ((140, 230), (90, 70)):
            # Blobs with holes and dents, at and off the raster's edges, and specks.
            mask = np.zeros(shape, np.uint8)
            for _ in range(4):
                centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
                axes = (int(rng.integers(5, 60)), int(rng.integers(5, 40)))
                cv2.ellipse(mask, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
            mask &= (rng.random(shape) < 0.85).astype(np.uint8)
            mask[rng.random(shape) < 0.01] = 1
            np.testing.assert_array_equal(disc_closing(mask, size), cv2.morphologyEx(mask, cv2.MORPH_CLOSE, disc))
