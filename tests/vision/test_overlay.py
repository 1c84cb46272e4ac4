"""The overlay's drawing helpers: the outline's heights from the glue path, computed in blocks."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import FailureKind
from cellctl.vision import overlay
from cellctl.vision.sole_result import GluePath, MeasurementRefused, SoleMeasurement


def _measurement(outline: np.ndarray, path: np.ndarray) -> SoleMeasurement:
    return SoleMeasurement(
        length_mm=0.0,
        heel_height_mm=0.0,
        toe_height_mm=0.0,
        glue_path=GluePath(path, np.tile([0.0, 0.0, 1.0], (len(path), 1))),
        points=0,
        axis=np.array([1.0, 0.0]),
        heel_point=np.zeros(3),
        toe_point=np.zeros(3),
        outline=outline,
        half_area_difference=0.0,
        camera_to_table=np.eye(4),
    )


@pytest.mark.parametrize("seed", range(6))
def test_the_outlines_heights_are_the_nearest_path_points_as_the_whole_distance_matrix_gives_them(seed: int) -> None:
    """Block by block, the same nearest path point for every outline point as np.linalg.norm over the whole
    outline x path matrix, ties included (integer coordinates: many points at equal distances, where argmin's
    first-of-equals must pick the same one)."""
    rng = np.random.default_rng(seed)
    count = 3 * overlay._EDGE_ROWS + 17  # several blocks and a short last one
    outline = rng.normal(size=(count, 2)) * 40.0
    path = np.column_stack([rng.normal(size=(300, 2)) * 40.0, rng.normal(size=300)])
    if seed % 2:
        outline, path[:, :2] = np.round(outline / 8.0), np.round(path[:, :2] / 8.0)
    dense = path[np.argmin(np.linalg.norm(outline[:, None, :] - path[None, :, :2], axis=2), axis=1), 2]
    heights = overlay._edge_heights(_measurement(outline, path))
    assert np.array_equal(heights, dense)


def test_an_empty_outline_has_no_heights_and_a_refused_measurements_lies_on_the_table() -> None:
    assert overlay._edge_heights(_measurement(np.zeros((0, 2)), np.ones((3, 3)))).shape == (0,)
    refused = MeasurementRefused(FailureKind.TOO_FEW_POINTS, "test", 0, outline=np.ones((5, 2)))
    assert np.array_equal(overlay._edge_heights(refused), np.zeros(5))
