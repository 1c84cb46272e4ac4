"""Isolated specks of depth draw no footprint: a few specks the matcher left over an unmeasured shadow band beside
the sole no longer bulge its outline (cellctl.vision.segmentation)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from cellctl.vision.cloud import StereoCloud
from cellctl.vision.footprint import Footprint
from cellctl.vision.segmentation import FOOTPRINT_CELL_MM, FOOTPRINT_OPEN_MM, _footprint, _footprint_votes
from cellctl.vision.sole_region import point_spread

FOCAL_PX, BASELINE_MM, DISTANCE_MM = 1400.0, 80.0, 540.0


def _scene() -> tuple[StereoCloud, np.ndarray, np.ndarray]:
    """A cloud of a flat sole top 150 x 40 mm seen from 540 mm (table frame = camera frame here, z up to the
    camera: the heights do not matter), one point per pixel, 3 % unmeasured, and beyond its edge at y = 39.3 mm
    a band the matcher could not measure but for specks at the top's height, 4 px apart along 8 mm of it, 1.2-2 mm
    out. Returns the cloud, its points and the specks' mask."""
    rng = np.random.default_rng(7)
    mm_per_px = DISTANCE_MM / FOCAL_PX
    xs, ys = np.meshgrid(np.arange(0, int(150 / mm_per_px)), np.arange(0, int(40 / mm_per_px)))
    xs, ys = xs.ravel(), ys.ravel()
    keep = rng.random(xs.size) > 0.03
    xs, ys = xs[keep], ys[keep]
    speck_x = np.arange(int(60 / mm_per_px), int(68 / mm_per_px), 4)
    speck_y = int(40 / mm_per_px) + 2 + 2 * (np.arange(len(speck_x)) % 2)
    xs, ys = np.concatenate([xs, speck_x]), np.concatenate([ys, speck_y])
    points = np.column_stack([xs * mm_per_px, ys * mm_per_px, np.full(xs.size, 20.0) + rng.normal(0, 0.1, xs.size)])
    disparity = np.full(xs.size, FOCAL_PX * BASELINE_MM / DISTANCE_MM)
    calibration: Any = SimpleNamespace(baseline_mm=BASELINE_MM)  # the spacing is all point_spread reads of it
    pixels = np.column_stack([xs, ys]).astype(np.float64)
    size = (int(xs.max()) + 1, int(ys.max()) + 1)
    cloud = StereoCloud(points, np.zeros((xs.size, 3), np.float32), pixels, disparity, size, calibration=calibration)
    specks = np.zeros(xs.size, bool)
    specks[-len(speck_x) :] = True
    return cloud, points, specks


def test_isolated_specks_beyond_the_edge_do_not_bulge_the_footprint() -> None:
    cloud, points, specks = _scene()
    everything = np.arange(len(points))
    spread = point_spread(cloud, everything, points)
    assert spread is not None
    assert np.array_equal(spread.isolated, specks)  # the specks, and nothing of the top's edge
    raster = Footprint.empty_like(points[:, :2], FOOTPRINT_CELL_MM)
    every = raster.counts(points)
    bulge, edge = np.array([[63.0, 40.0]]), np.array([[63.0, 39.2]])
    with_specks = _footprint(raster, every, raster.counts(points), FOOTPRINT_OPEN_MM)
    assert with_specks.contains(bulge)[0]  # the closing joins the specks to the top
    without = _footprint(raster, every, _footprint_votes(raster, points, everything, spread), FOOTPRINT_OPEN_MM)
    assert not without.contains(bulge)[0]
    assert without.contains(edge)[0]
    assert 0.995 * with_specks.area_mm2 < without.area_mm2 < with_specks.area_mm2  # the bulge only


def test_without_a_stereo_cloud_nothing_is_isolated() -> None:
    cloud, points, _ = _scene()
    cloud.calibration = None
    assert point_spread(cloud, np.arange(len(points)), points) is None
    raster = Footprint.empty_like(points[:, :2], FOOTPRINT_CELL_MM)
    votes = _footprint_votes(raster, points, np.arange(len(points)), None)
    assert np.array_equal(votes, raster.counts(points))
