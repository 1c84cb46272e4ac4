"""The share of the sole's pixels without depth counts a whole end that lost its depth (glare on a toe); its
disc closing is OpenCV's."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.cloud import StereoCloud
from cellctl.vision.footprint import largest_component
from cellctl.vision.sole_region import disc_closing, unmeasured_fraction


def _cloud(measured: np.ndarray) -> StereoCloud:
    """A cloud with one point per True pixel of `measured` (H x W); only the pixels matter here."""
    y, x = np.nonzero(measured)
    pixels = np.column_stack([x, y]).astype(np.float64)
    n = len(pixels)
    height, width = measured.shape
    return StereoCloud(np.zeros((n, 3)), np.zeros((n, 3), np.float32), pixels, np.full(n, 50.0), (width, height))


def test_a_changed_end_without_depth_beyond_the_measured_pixels_counts_as_unmeasured() -> None:
    shape = (300, 600)
    changed = np.zeros(shape, bool)
    changed[100:200, 100:420] = True  # the sole as the change test sees it
    measured = np.zeros(shape, bool)
    measured[100:200, 100:300] = True  # depth on all but its last 120 px (~47 mm, past the 61 px closing)
    cloud = _cloud(measured)
    index = np.arange(len(cloud.pixels))
    assert abs(unmeasured_fraction(cloud, changed, index) - 120 / 320) < 0.02


def test_a_changed_region_the_sole_does_not_touch_is_not_the_soles() -> None:
    shape = (300, 600)
    changed = np.zeros(shape, bool)
    changed[100:200, 100:300] = True
    changed[20:60, 450:580] = True  # something else changed, apart from the sole, with no depth
    measured = changed.copy()
    measured[20:60, 450:580] = False
    cloud = _cloud(measured)
    assert unmeasured_fraction(cloud, changed, np.arange(len(cloud.pixels))) == 0.0


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


def test_largest_component_is_opencvs_largest_by_its_statistics() -> None:
    """Labels counted with numpy name the same largest component as OpenCV's statistics (ties: the first)."""
    rng = np.random.default_rng(7)
    for k in range(40):
        shape = (int(rng.integers(1, 160)), int(rng.integers(1, 160)))
        mask = (rng.random(shape) < rng.uniform(0.0, 0.7)).astype(np.uint8)
        if k % 4 == 0:  # two equal squares: the first in raster order wins
            mask[:] = 0
            mask[:3, :3] = 1
            mask[-3:, -3:] = 1
        count, expected_labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        labels, largest = largest_component(mask)
        np.testing.assert_array_equal(labels, expected_labels)
        assert largest == (1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) if count > 1 else 0)
