"""Teach markers located by the cameras, on a rendered table carrying ArUco markers at known positions.

The simulator's table texture gets the markers pasted in (the renderer traces the true geometry, so the
images are what the rig would see); `cellctl teach-robot --locate` measures them, a simulated robot fills in
its readings, and the transform is solved from the cell's own measurements.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.cli import main
from cellctl.sim.render import SceneRenderer
from cellctl.sim.scene import SoleScene
from cellctl.vision.calibration import Calibration
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.robot_frame import RigidTransform, load_robot_frame
from cellctl.vision.table import find_table
from cellctl.vision.teach_target import locate_markers, marker_image
from tests.vision.test_robot_frame import rotation

pytestmark = pytest.mark.slow  # one full-size render and match

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
WANTED = {0: (-120.0, -60.0), 1: (100.0, -70.0), 2: (130.0, 80.0), 3: (-90.0, 90.0), 7: (10.0, 5.0)}
MARKER_MM = 30.0


@pytest.fixture(scope="module")
def table_with_markers():  # noqa: ANN201 - (scene, pair, true centres)
    calib = Calibration.load(DEPLOY / "sim-calib.yaml")
    scene = dataclasses.replace(SoleScene.random(0, "white", calib), sole=None)
    renderer = SceneRenderer(calib, scene.camera_pose, None, "white", 0)
    texture = renderer._table_texture  # the table's brightness map, texels on a 0.25 mm grid
    texels = int(MARKER_MM / texture.texel_mm)
    truth = {}
    for marker_id, (x, y) in WANTED.items():
        column = int(round((x - texture.origin[0]) / texture.texel_mm - texels / 2))
        row = int(round((y - texture.origin[1]) / texture.texel_mm - texels / 2))
        # Rows run along +y of the table, which the downward-looking camera sees as -y: flip to print it right.
        printed = np.flipud(marker_image(marker_id, texels).astype(np.float32) / 255.0)
        texture.image[row : row + texels, column : column + texels] = 0.2 + 4.0 * printed
        centre = np.array([column, row]) + (texels - 1) / 2
        truth[marker_id] = np.array([*(np.array(texture.origin) + centre * texture.texel_mm), 0.0])
    return calib, scene, renderer.render(), truth


def test_markers_are_located_within_a_few_tenths_of_a_millimetre(table_with_markers) -> None:  # noqa: ANN001
    calib, scene, pair, truth = table_with_markers
    table = find_table(SoleReconstructor(calib).points_from_disparity(pair.left, pair.right).points)
    assert table is not None
    targets = locate_markers(calib, pair.left, pair.right, table)
    assert [t.marker_id for t in targets] == sorted(WANTED)
    to_scene = scene.table_from_measured(table.camera_to_table())
    errors = np.array([to_scene[:3, :3] @ t.table_xyz + to_scene[:3, 3] - truth[t.marker_id] for t in targets])
    assert np.abs(errors[:, :2]).max() < 0.2 and np.abs(errors[:, 2]).max() < 0.4, np.round(errors, 3)


def test_locate_then_teach_through_the_cli(table_with_markers, tmp_path: Path) -> None:  # noqa: ANN001
    calib, scene, pair, truth = table_with_markers
    for side, image in (("left", pair.left), ("right", pair.right)):
        cv2.imwrite(str(tmp_path / f"{side}.png"), image)
    config = tmp_path / "cell.toml"
    config.write_text(
        f'[cameras]\nbackend = "simulated"\n[calibration]\npath = "{DEPLOY / "sim-calib.yaml"}"\n'
        f'[journal]\nstate_dir = "{tmp_path / "state"}"\n'
    )
    points = tmp_path / "teach.csv"
    assert main(["teach-robot", str(points), "--config", str(config), "--locate", str(tmp_path / "left.png"), str(tmp_path / "right.png")]) == 0  # fmt: skip
    # The robot (base pose known to the test only) touches each marker centre and notes its reading.
    robot_from_scene = RigidTransform(rotation(np.array([0.1, 0.2, 1.0]), -35.0), np.array([640.0, 310.0, -120.0]))
    rows = points.read_text().splitlines()
    filled = rows[:2]
    for row in rows[2:]:
        marker, _, _, _, *cell = row.split(",")
        reading = robot_from_scene.apply(truth[int(marker)][None])[0]
        filled.append(",".join([marker, *(f"{v:.3f}" for v in reading), *cell]))
    points.write_text("\n".join(filled) + "\n")
    frame = tmp_path / "robot-frame.json"
    assert main(["teach-robot", str(points), "--frame", str(frame)]) == 0
    # Over the markers' area, the taught transform puts the cell's points where the robot touched.
    table = find_table(SoleReconstructor(calib).points_from_disparity(pair.left, pair.right).points)
    assert table is not None
    truth_table_to_robot = robot_from_scene.matrix @ scene.table_from_measured(table.camera_to_table())
    where = np.array([[x, y, z] for x in (-120, 0, 130) for y in (-70, 0, 90) for z in (0, 30)], float)
    solved = load_robot_frame(frame)
    error = np.linalg.norm(solved.apply(where) - RigidTransform.from_matrix(truth_table_to_robot).apply(where), axis=1)
    assert error.max() < 0.5, error.max()


def test_locate_live_grabs_from_the_configured_cameras(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from tests.sim_rig import write_half_size_rig

    config = tmp_path / "cell.toml"
    config.write_text(
        f'[cameras]\nbackend = "simulated"\n[cameras.simulated]\nseeds = [1]\n'
        f'[calibration]\npath = "{write_half_size_rig(tmp_path)}"\n[journal]\nstate_dir = "{tmp_path / "state"}"\n'
    )
    # The simulated cell shows a sole and no markers: grabbed, matched, table found, and said so.
    assert main(["teach-robot", str(tmp_path / "teach.csv"), "--config", str(config), "--locate-live"]) == 1
    assert "no teach marker" in capsys.readouterr().out and not (tmp_path / "teach.csv").exists()
