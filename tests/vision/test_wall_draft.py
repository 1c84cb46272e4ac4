"""A stated wall draft (cellctl.vision.wall_draft): the top edge the cameras see is moved out to the foot they cannot
see, by the top's height x tan(draft); unstated, a drafted sole is measured at its top edge, short."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.cameras.base import StereoFrame
from cellctl.errors import FailureKind
from cellctl.eval.sole_bench import glue_truth
from cellctl.service.cycle import Measured, MeasureSettings, Refused, measure_frame
from cellctl.sim.look import SceneLook
from cellctl.sim.rig import default_rig
from cellctl.sim.scene import SoleScene, true_cloud
from cellctl.vision.measurement import SoleMeasurement, measure_sole
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.wall_draft import MIN_TOP_INSET_MM, check_draft, check_glue_inset, foot_outline


def _circle(radius: float, n: int = 400) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return radius * np.column_stack([np.cos(t), np.sin(t)])  # counter-clockwise


def test_the_foot_lies_out_by_the_run_along_the_normals() -> None:
    runs = np.full(400, 1.5)
    foot = foot_outline(_circle(40.0), runs)
    np.testing.assert_allclose(np.linalg.norm(foot, axis=1), 41.5, atol=1e-9)


@pytest.mark.parametrize("draft", [0.0, -2.0, 10.5, float("nan")])
def test_a_draft_outside_what_a_recipe_may_state_is_refused(draft: float) -> None:
    with pytest.raises(ValueError, match="draft must be in"):
        check_draft(draft)


def test_the_glue_line_must_stay_inside_the_top_edge() -> None:
    assert check_glue_inset(np.full(10, 0.9), 2.0) is None
    problem = check_glue_inset(np.array([0.5, 1.6, 0.8]), 2.0)
    assert problem is not None and problem.kind is FailureKind.GLUE_PATH_INCONSISTENT
    assert "up to 1.6 mm beyond its top edge" in problem.reason
    assert f"offset_mm to {1.6 + MIN_TOP_INSET_MM:.1f} or more" in problem.reason


def _drafted_scene() -> SoleScene:
    # A normal sole whose wall leans out 3 degrees from the table: hidden behind its top edge from both cameras.
    return SoleScene.random(2, "white", default_rig(), SceneLook(wall_slope_deg=3.0, wall_foot_mm=0.0))


def test_a_drafted_sole_is_short_unless_its_draft_is_stated() -> None:
    rig, scene = default_rig(), _drafted_scene()
    assert scene.sole is not None
    pair = scene.render()
    reconstruction = SoleReconstructor(rig).segment(true_cloud(rig, pair.depth_left, pair.left))
    truth = scene.sole.truth().length_mm
    unstated = measure_sole(reconstruction, glue_offset_mm=4.0)
    assert isinstance(unstated, SoleMeasurement), unstated.reason
    assert unstated.length_mm - truth < -1.0  # the top edge: the error this module exists for
    stated = measure_sole(reconstruction, glue_offset_mm=4.0, wall_draft_deg=3.0)
    assert isinstance(stated, SoleMeasurement), stated.reason
    assert abs(stated.length_mm - truth) < 0.5
    # The glue line too is taken from the foot: 4 mm inside it (the true outline), within the 1 mm tolerance.
    assert _worst_glue_inset_error(scene, stated, 4.0) < 1.0
    assert _worst_glue_inset_error(scene, unstated, 4.0) > 1.0


def _worst_glue_inset_error(scene: SoleScene, result: SoleMeasurement, offset_mm: float) -> float:
    transform = scene.table_from_measured(result.camera_to_table)
    points = result.glue_path.points @ transform[:3, :3].T + transform[:3, 3]
    inset, _, _ = glue_truth(scene, points[:, :2])
    return float(np.abs(inset - offset_mm).max())


def test_the_recipes_draft_reaches_the_measurement_through_the_cycle() -> None:
    rig, scene = default_rig(), _drafted_scene()
    assert scene.sole is not None
    pair = scene.render()
    frame, reconstructor = StereoFrame(pair.left, pair.right, 0.0, 0.0), SoleReconstructor(rig)
    # A glue line 1 mm inside the foot would lie on the heel's top edge (the run there is ~1 mm): refused.
    near_edge = measure_frame(frame, reconstructor, MeasureSettings(1.0, 2.0, wall_draft_deg=3.0))
    assert isinstance(near_edge, Refused) and near_edge.failure is FailureKind.GLUE_PATH_INCONSISTENT
    measured = measure_frame(frame, reconstructor, MeasureSettings(2.0, 2.0, wall_draft_deg=3.0))
    assert isinstance(measured, Measured), measured.reason
    assert abs(measured.measurement.length_mm - scene.sole.truth().length_mm) < 1.0
