"""A footprint's cells beyond a line (the measurement's half areas, which orient the axis heel -> toe): counted by
rows of the raster's integral image, the same counts as projecting every marked cell's centre."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.footprint import Footprint


def blob(seed: int) -> Footprint:
    """An irregular raster: a random ellipse with holes, off the origin, with 0.25 mm cells."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:300, 0:420]
    a, b = rng.uniform(60, 190), rng.uniform(40, 140)
    mask = ((cols - 210) / a) ** 2 + ((rows - 150) / b) ** 2 < 1.0
    mask &= rng.random(mask.shape) > 0.2
    return Footprint(mask.astype(np.uint8), (float(rng.uniform(-80, 80)), float(rng.uniform(-80, 80))), 0.25)


def projected(footprint: Footprint, point: np.ndarray, direction: np.ndarray, offset: float) -> tuple[int, int]:
    proj = (footprint.centres() - point) @ direction
    return int(np.count_nonzero(proj > offset)), len(proj)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cells_beyond_a_line_are_those_whose_centres_project_beyond_it(seed: int) -> None:
    footprint = blob(seed)
    rng = np.random.default_rng(seed + 10)
    point = footprint.centres().mean(axis=0) + rng.normal(0.0, 3.0, 2)
    # Every heading: the axis-aligned ones exactly (no column step) and a hair off them (a step of ~1e-17).
    angles = np.concatenate([rng.uniform(0, 2 * np.pi, 40), np.arange(8) * np.pi / 4])
    exact = [np.array(d, np.float64) for d in ((1, 0), (0, 1), (-1, 0), (0, -1))]
    for angle, direction in [(a, np.array([np.cos(a), np.sin(a)])) for a in angles] + [(None, d) for d in exact]:
        for offset in (-20.0, -1.3, 0.0, 0.7, 15.0, 1e4):
            beyond, total = footprint.cells_beyond(point, direction, offset)
            want, cells = projected(footprint, point, direction, offset)
            assert total == cells
            # a cell centre within rounding of the line may count either way
            assert abs(beyond - want) <= 1, (angle, offset, beyond, want)


def test_an_empty_footprint_has_no_cells_beyond_any_line() -> None:
    empty = Footprint(np.zeros((10, 12), np.uint8), (0.0, 0.0), 0.5)
    assert empty.cells_beyond(np.zeros(2), np.array([1.0, 0.0]), 0.0) == (0, 0)
