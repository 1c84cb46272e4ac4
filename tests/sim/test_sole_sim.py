"""The simulated sole: its analytic truth, its mesh, its rendering through the rig and `cellctl simulate sole`."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from cellctl.cli import main
from cellctl.sim.render import project
from cellctl.sim.rig import default_rig
from cellctl.sim.scene import SoleScene
from cellctl.sim.sole import (
    HEEL_HEIGHT_RANGE_MM,
    LENGTH_RANGE_MM,
    TOE_HEIGHT_RANGE_MM,
    SoleModel,
    SolePose,
    SoleShape,
    _clip_half_plane,
    _polygon_area,
    _polygon_moments,
)


def model(seed: int, pose: SolePose | None = None) -> SoleModel:
    return SoleModel(SoleShape.random(np.random.default_rng(seed)), pose or SolePose(0.0, 0.0, 0.0, False))


@pytest.fixture(scope="module")
def scene() -> SoleScene:
    return SoleScene.random(4, "white", default_rig())


@pytest.fixture(scope="module")
def rendered(scene: SoleScene):  # noqa: ANN201
    return scene.render()


# ---- geometry helpers ---------------------------------------------------------------------------------


def test_polygon_moments_of_a_rotated_rectangle() -> None:
    a = np.radians(30.0)
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    corners = np.array([[-50.0, -10.0], [50.0, -10.0], [50.0, 10.0], [-50.0, 10.0]]) @ rotation.T + [7.0, -3.0]
    area, centroid, cov = _polygon_moments(corners)
    assert area == pytest.approx(2000.0)
    np.testing.assert_allclose(centroid, [7.0, -3.0], atol=1e-9)
    eigvals, eigvecs = np.linalg.eigh(cov)
    assert eigvals[1] == pytest.approx(100.0**2 / 12)  # second moment per area of the long side
    assert abs(eigvecs[:, 1] @ [np.cos(a), np.sin(a)]) == pytest.approx(1.0)


def test_half_plane_clip_halves_a_square() -> None:
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    assert _polygon_area(_clip_half_plane(square, np.array([1.0, 0.0]), 2.5)) == pytest.approx(75.0)
    assert _polygon_area(_clip_half_plane(square, np.array([0.0, -1.0]), -4.0)) == pytest.approx(40.0)


# ---- truth ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_truth_follows_the_definitions(seed: int) -> None:
    sole = model(seed)
    truth = sole.truth()
    outline = sole.outline_table()
    axis = np.array(truth.axis)
    proj = outline @ axis
    assert truth.length_mm == pytest.approx(proj.max() - proj.min(), abs=1e-9)
    # The model's toe (u = L) is the end the half-area rule picks: the forefoot is wider.
    tip_to_tip = (
        sole.pose.to_table(
            [[sole.shape.length, sole.shape.centre_line(np.array(sole.shape.length))]], sole.shape.length
        )[0]
        - sole.pose.to_table([[0.0, 0.0]], sole.shape.length)[0]
    )
    assert tip_to_tip @ axis > 0.95 * sole.shape.length
    assert truth.half_area_difference > 0.08
    heel, toe = np.array(truth.heel_point), np.array(truth.toe_point)
    assert (heel[:2] @ axis - proj.min()) == pytest.approx(0.1 * truth.length_mm)
    assert (proj.max() - toe[:2] @ axis) == pytest.approx(0.1 * truth.length_mm)
    assert truth.heel_height_mm == pytest.approx(sole.top_height_at(heel[None, :2])[0])
    assert LENGTH_RANGE_MM[0] - 1 <= truth.length_mm <= LENGTH_RANGE_MM[1] + 1
    assert HEEL_HEIGHT_RANGE_MM[0] - 1.5 <= truth.heel_height_mm <= HEEL_HEIGHT_RANGE_MM[1] + 1.5
    assert TOE_HEIGHT_RANGE_MM[0] - 1.5 <= truth.toe_height_mm <= TOE_HEIGHT_RANGE_MM[1] + 1.5


def test_truth_does_not_depend_on_where_the_sole_lies() -> None:
    here = model(3).truth()
    there = model(3, SolePose(-40.0, 25.0, 147.0, True)).truth()
    assert there.length_mm == pytest.approx(here.length_mm, abs=1e-6)
    assert there.heel_height_mm == pytest.approx(here.heel_height_mm, abs=1e-6)
    assert there.toe_height_mm == pytest.approx(here.toe_height_mm, abs=1e-6)


def test_shapes_vary_with_the_seed() -> None:
    lengths = [model(seed).truth().length_mm for seed in range(8)]
    assert np.ptp(lengths) > 20.0


def test_mesh_is_the_modelled_surface() -> None:
    """Rays cast down onto the mesh meet the analytic top surface and the footprint ends where the outline does."""
    sole = model(5, SolePose(10.0, -5.0, 20.0, True))
    vertices, triangles, _ = sole.mesh()
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(triangles)
    scene.add_triangles(mesh)
    truth = sole.truth()
    axis = np.array(truth.axis)
    probes = np.array([truth.heel_point[:2], truth.toe_point[:2]])
    # Just inside and just outside the toe tip along the axis.
    tip = sole.outline_table()[np.argmax(sole.outline_table() @ axis)]
    probes = np.vstack([probes, tip - 0.05 * axis, tip + 0.05 * axis])
    rays = np.column_stack([probes, np.full(len(probes), 200.0), np.zeros((len(probes), 2)), -np.ones(len(probes))])
    hit_z = 200.0 - scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    assert hit_z[0] == pytest.approx(truth.heel_height_mm, abs=0.01)
    assert hit_z[1] == pytest.approx(truth.toe_height_mm, abs=0.01)
    assert np.isfinite(hit_z[2]) and not np.isfinite(hit_z[3])


# ---- rendering --------------------------------------------------------------------------------------


def test_random_scene_keeps_the_sole_in_both_views(scene: SoleScene) -> None:
    assert scene.in_view(20)
    outline = scene.sole.outline_table(200)
    for side in ("left", "right"):
        px = project(scene.calib, scene.camera_pose, side, np.column_stack([outline, np.zeros(len(outline))]))
        assert np.all(px > 0) and np.all(px < scene.calib.image_size)


def test_render_is_a_colour_pair_with_true_depth(scene: SoleScene, rendered) -> None:  # noqa: ANN001
    width, height = scene.calib.image_size
    assert rendered.left.shape == rendered.right.shape == (height, width, 3)
    assert rendered.left.dtype == np.uint8
    assert not np.array_equal(rendered.left, rendered.right)
    # True depth at the pixel where the left camera sees the heel point is that point's camera depth.
    heel = np.array(scene.sole.truth().heel_point)
    px = project(scene.calib, scene.camera_pose, "left", heel[None])[0]
    camera = np.linalg.inv(scene.camera_pose) @ np.append(heel, 1.0)
    assert rendered.depth_left[int(round(px[1])), int(round(px[0]))] == pytest.approx(camera[2], abs=0.3)
    assert rendered.sole_mask_left[int(round(px[1])), int(round(px[0]))]


def test_white_sole_on_dark_table_with_low_texture(scene: SoleScene, rendered) -> None:  # noqa: ANN001
    grey = cv2.cvtColor(rendered.left, cv2.COLOR_BGR2GRAY).astype(np.float64)
    sole = cv2.erode(rendered.sole_mask_left.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    table = cv2.dilate(rendered.sole_mask_left.astype(np.uint8), np.ones((61, 61), np.uint8)) == 0
    assert grey[sole].mean() > 3 * grey[table].mean()
    # Weak texture: a few per cent of contrast, not a dot pattern.
    assert 0.02 < grey[sole].std() / grey[sole].mean() < 0.12
    assert grey[table].mean() < 60


def test_black_sole_is_darker_and_render_is_repeatable() -> None:
    black = SoleScene.random(4, "black", default_rig())
    first, second = black.render(), black.render()
    assert np.array_equal(first.left, second.left)
    grey = cv2.cvtColor(first.left, cv2.COLOR_BGR2GRAY)[first.sole_mask_left]
    assert grey.mean() < 100


def test_simulate_sole_command_writes_the_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "sole", "--out", str(tmp_path), "--seed", "4", "--color", "black"]) == 0
    for name in ("left.png", "right.png", "truth.json", "depth_left.npy", "outline.npy", "calib.yaml"):
        assert (tmp_path / name).is_file(), name
    truth = json.loads((tmp_path / "truth.json").read_text())
    expected = SoleScene.random(4, "black", default_rig()).sole.truth()
    assert truth["length_mm"] == pytest.approx(expected.length_mm)
    assert truth["seed"] == 4 and truth["color"] == "black"
    assert {"heel_height_mm", "toe_height_mm", "sole_pose", "camera_pose"} <= truth.keys()
    assert np.load(tmp_path / "depth_left.npy").shape == (1024, 1280)
    assert "length" in capsys.readouterr().out


def test_simulate_sole_rejects_an_unknown_colour(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "sole", "--out", str(tmp_path), "--color", "red"]) == 2
    assert "--color 'red' is not one of black, white" in capsys.readouterr().err
