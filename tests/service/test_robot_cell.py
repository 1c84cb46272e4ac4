"""End to end for issue 14: the service with map v2, recipes, the taught robot frame and OPC UA.

A simulated robot with a known base pose is taught through `cellctl teach-robot` (noisy touch points, one
wrong point); then the PLC simulator selects recipes by register and triggers cycles over Modbus TCP, and an
asyncua client subscribed to the service's OPC UA server receives one event per cycle. The glue points the
PLC receives in robot coordinates are compared with the simulated sole's true surface, on the full-size rig
of deploy/sim-calib.yaml where the measurement's 1.3 mm tolerance is defined (tests/service/test_daemon.py).
"""

from __future__ import annotations

import asyncio
import json
import math
import shutil
import threading
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from asyncua import Client

from cellctl.cli import main
from cellctl.service.config import CellConfig
from cellctl.service.daemon import Daemon
from cellctl.service.journal import Journal
from cellctl.service.opcua import NAMESPACE
from cellctl.service.station import Station
from cellctl.sim.scene import SoleScene
from cellctl.vision.calibration import Calibration
from cellctl.vision.reconstruction import SoleReconstructor
from cellctl.vision.robot_frame import RigidTransform, load_robot_frame
from firmware_io.plc_sim import CycleReading, PlcSimulator
from firmware_io.registers import ErrorCode, FeatureBit, GlueFrame, StatusBit
from tests.sim_rig import UNTAUGHT_MEASURE
from tests.vision.test_robot_frame import rotation

pytestmark = pytest.mark.slow  # real service cycles on rendered scenes

TOLERANCE_MM = 1.3  # the measurement's own acceptance tolerance (issue 2, Wang et al. Table 4)
SEED = 1
DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
#: The simulated robot's base pose: scene (true table) frame -> robot base.
ROBOT_FROM_SCENE = RigidTransform(rotation(np.array([0.2, -0.1, 1.0]), 152.0), np.array([812.0, -240.5, -95.0]))


class Cell:
    """The service in a thread, plus the scene it sees and the taught transform."""

    def __init__(self, directory: Path) -> None:
        calib_path = directory / "sim-calib.yaml"
        shutil.copy(DEPLOY / "sim-calib.yaml", calib_path)
        self.calib = Calibration.load(calib_path)
        self.scene = SoleScene.random(seed=SEED, color="white", calib=self.calib)
        self.truth = self.scene.sole.truth()
        measured_to_scene = self._teach(directory, calib_path)
        self.truth_table_to_robot = RigidTransform.from_matrix(ROBOT_FROM_SCENE.matrix @ measured_to_scene)
        self.config = CellConfig.load(self._write_config(directory, calib_path))
        self.daemon = Daemon(self.config)
        self.station = Station.attach(self.daemon, port=0)  # the operator station shows the active recipe
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert self.daemon.wait_started(60), f"service did not start: {self.error}"

    def _run(self) -> None:
        try:
            self.daemon.run()
        except BaseException as exc:
            self.error = exc

    def _teach(self, directory: Path, calib_path: Path) -> np.ndarray:
        """Teach through the CLI; returns the measured table -> scene map of this rig."""
        pair = self.scene.render()
        reconstruction = SoleReconstructor(self.calib).reconstruct(pair.left, pair.right)
        assert reconstruction.camera_to_table is not None
        measured_to_scene = self.scene.table_from_measured(reconstruction.camera_to_table)
        rng = np.random.default_rng(3)
        scene_points = np.column_stack([rng.uniform(-150, 150, 9), rng.uniform(-100, 100, 9), rng.uniform(0, 40, 9)])
        to_measured = RigidTransform.from_matrix(np.linalg.inv(measured_to_scene))
        cell = to_measured.apply(scene_points) + rng.normal(scale=0.05, size=scene_points.shape)
        robot = ROBOT_FROM_SCENE.apply(scene_points) + rng.normal(scale=0.05, size=scene_points.shape)
        robot[4] += np.array([3.0, 3.0, -2.0])  # a wrong touch
        rows = ["robot_x,robot_y,robot_z,cell_x,cell_y,cell_z"]
        rows += [",".join(f"{v:.4f}" for v in (*r, *c)) for r, c in zip(robot, cell)]
        (directory / "teach.csv").write_text("\n".join(rows) + "\n")
        frame = calib_path.with_name("robot-frame.json")
        assert main(["teach-robot", str(directory / "teach.csv"), "--frame", str(frame)]) == 0
        return measured_to_scene

    def _write_config(self, directory: Path, calib_path: Path) -> Path:
        recipes = directory / "recipes"
        recipes.mkdir()
        t = self.truth
        (recipes / "good.toml").write_text(
            f'number = 1\nname = "Runner 42"\n[glue]\noffset_mm = 2.0\n'
            f"[length_mm]\nnominal = {t.length_mm + 0.5:.2f}\ntolerance = 3.0\n"
            f"[heel_height_mm]\nnominal = {t.heel_height_mm:.2f}\ntolerance = 2.0\n"
            f"[toe_height_mm]\nnominal = {t.toe_height_mm:.2f}\ntolerance = 2.0\n"
        )
        (recipes / "long.toml").write_text(
            f'number = 2\nname = "Runner 44"\n[glue]\noffset_mm = 4.0\n'
            f"[length_mm]\nnominal = {t.length_mm + 12:.2f}\nminus = 2.0\nplus = 2.0\n"
        )
        (recipes / "deep.toml").write_text('number = 3\nname = "Platform"\ndepth_range_mm = [430.0, 670.0]\n')
        path = directory / "cell.toml"
        # liveness_timeout_s 30 and cycle_timeout_s 15 (below the simulated PLC's 20 s wait): a full-size cycle
        # can pass the defaults (5 s, 4 s) on the shared, loaded test machine, and the heartbeat would stop or
        # the cycle be answered CYCLE_TIMEOUT by design; this test is about recipes, frames and OPC UA.
        path.write_text(
            f'[cameras]\nbackend = "simulated"\n[cameras.simulated]\nseeds = [{SEED}]\n'
            f'[calibration]\npath = "{calib_path}"\n[plc]\nport = 0\nmap_version = 2\nliveness_timeout_s = 30\ncycle_timeout_s = 15\n'
            f'[recipes]\ndir = "{recipes}"\n[robot]\npublish_frame = "robot"\n'
            f'[opcua]\nenabled = true\nendpoint = "opc.tcp://127.0.0.1:0/cellctl/"\ncell_name = "cell-3"\n'
            f"allow_anonymous = true\n"
            f'[journal]\nstate_dir = "{directory / "state"}"\nkeep_artifacts = 3\n{UNTAUGHT_MEASURE}'
        )
        return path

    def stop(self) -> None:
        self.daemon.request_stop()
        self.thread.join(30)
        self.station.stop()
        assert not self.thread.is_alive() and self.error is None


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    running = Cell(tmp_path_factory.mktemp("robot-cell"))
    yield running
    running.stop()


def test_the_taught_transform_is_close_to_the_robots_true_pose(cell: Cell) -> None:
    solved = load_robot_frame(cell.config.robot_frame_path)
    working = cell.scene.sole.outline_table(64)
    where = np.column_stack([working, np.full(len(working), 20.0)])
    error = np.linalg.norm(solved.apply(where) - cell.truth_table_to_robot.apply(where), axis=1).max()
    # 0.05 mm noise on the robot's and the cell's side of 9 points: a few tenths at the sole's far end at most
    # (the 0.1 mm / 0.05 degree figures with touch noise alone: tests/vision/test_robot_frame.py).
    assert error < 0.3 and solved.angle_to_deg(cell.truth_table_to_robot) < 0.1


def check_against_the_sole(cell: Cell, reading: CycleReading, offset_mm: float) -> None:
    """Glue points in robot coordinates, mapped back through the TRUE base pose onto the true sole."""
    scene = ROBOT_FROM_SCENE.inverse()
    xyz = scene.apply(reading.glue_points.astype(float))
    outline = cell.scene.sole.outline_table(4000).astype(np.float32).reshape(-1, 1, 2)
    inset = np.array([cv2.pointPolygonTest(outline, (float(x), float(y)), True) for x, y in xyz[:, :2]])
    assert np.all(np.abs(inset - offset_mm) < TOLERANCE_MM), (inset.min(), inset.max())
    height = xyz[:, 2] - cell.scene.sole.top_height_at(xyz[:, :2])
    assert np.abs(height).max() < TOLERANCE_MM, np.abs(height).max()
    normals = scene.rotate(reading.glue_normals.astype(float))
    angles = np.degrees(np.arccos(np.clip(np.sum(normals * cell.scene.sole.top_normal_at(xyz[:, :2]), 1), -1, 1)))
    assert np.median(angles) < 5.0, np.median(angles)


class Events:
    def __init__(self) -> None:
        self.queue: asyncio.Queue[Any] = asyncio.Queue()

    def event_notification(self, event: Any) -> None:
        self.queue.put_nowait(event)


def test_recipes_by_register_robot_frame_points_and_one_opcua_event_per_cycle(cell: Cell) -> None:
    assert cell.daemon.opcua is not None

    async def scenario() -> list[CycleReading]:
        async with Client(cell.daemon.opcua.endpoint, timeout=10) as client:
            idx = await client.get_namespace_index(NAMESPACE)
            events = Events()
            subscription = await client.create_subscription(50, events)
            event_type = await client.nodes.root.get_child(
                ["0:Types", "0:EventTypes", "0:BaseEventType", f"{idx}:ResultReadyEventType"]
            )
            await subscription.subscribe_events(client.nodes.server, event_type)
            readings = []
            with PlcSimulator(cell.daemon.link.endpoint, map_version=2) as plc:  # type: ignore[arg-type]
                for recipe in (1, 2, 3, 99):
                    readings.append(await asyncio.to_thread(plc.run_cycle, None, 20.0, recipe=recipe))
                    event = await asyncio.wait_for(events.queue.get(), 10)
                    assert event.Cycle == readings[-1].cycle and event.RecipeId == recipe
            assert events.queue.empty()  # one event per cycle, not more
            last = await client.nodes.objects.get_child(
                [f"{idx}:cell-3", f"{idx}:ResultManagement", f"{idx}:LastResult"]
            )
            values = {(await n.read_browse_name()).Name: await n.read_value() for n in await last.get_children()}
            assert values["Cycle"] == readings[-1].cycle and values["ErrorCode"] == ErrorCode.RECIPE_UNKNOWN
            assert values["ResultState"] == "Error" and values["IsPass"] is False
            return readings

    good, long, deep, unknown = asyncio.run(scenario())
    # Recipe 1: in tolerance, 2 mm glue offset, points and normals in the robot's base frame.
    assert good.ok and good.in_tolerance is True and good.feature_fails == FeatureBit(0)
    assert good.glue_frame == GlueFrame.ROBOT_BASE and good.glue_offset_mm == 2.0 and good.nozzle_offset_mm == 0.0
    check_against_the_sole(cell, good, 2.0)
    # Recipe 2, the very next cycle: its offset and its (failing) length tolerance apply.
    assert long.ok and long.in_tolerance is False and long.feature_fails == FeatureBit.LENGTH
    assert long.status & StatusBit.OUT_OF_TOLERANCE and long.glue_offset_mm == 4.0
    check_against_the_sole(cell, long, 4.0)
    # Recipe 3: its own depth range (a second matcher), no tolerances: measured, nothing checked.
    assert deep.ok and deep.in_tolerance is None and deep.recipe == 3 and deep.glue_offset_mm == 2.0
    check_against_the_sole(cell, deep, 2.0)
    # An unknown recipe number: the documented error code, and the number echoed.
    assert unknown.error_code == ErrorCode.RECIPE_UNKNOWN and unknown.recipe == 99 and not unknown.ok
    assert math.isnan(unknown.length_mm)
    assert cell.daemon.active_recipe is not None and cell.daemon.active_recipe.number == 3
    # The station shows the active recipe (the last valid one) and the last cycle's recipe number.
    url = cell.station.url
    assert url is not None
    with urllib.request.urlopen(url.rstrip("/") + "/api/state", timeout=10) as reply:
        assert json.loads(reply.read())["recipe"] == [3, "Platform"]
    with urllib.request.urlopen(url.rstrip("/") + "/fragments/last", timeout=10) as reply:
        assert '<td id="last-recipe">99</td>' in reply.read().decode()
    # The journal keeps the same: durable before the PLC heard of it.
    journal = Journal.open(cell.config.journal.state_dir, readonly=True)
    rows = [journal.find(reading.cycle) for reading in (good, long, deep, unknown)]
    assert [(r.recipe, r.in_tolerance, r.failed_features) for r in rows if r is not None] == [
        (1, True, []),
        (2, False, ["LENGTH"]),
        (3, None, []),
        (99, None, []),
    ]
    journal.close()
