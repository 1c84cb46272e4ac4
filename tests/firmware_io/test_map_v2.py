"""Register map version 2 (recipes, tolerance bits, normals, frame) over Modbus TCP on 127.0.0.1.

Read three ways: the handshake directly, `PlcSimulator` (what `cellctl plc-sim` does), and mbpoll, a
Modbus master nobody here wrote (Debian package mbpoll, installed by the Makefile's APT_PACKAGES). Version 1
stays what PLCs already programmed for it read.
"""

from __future__ import annotations

import re
import subprocess
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from firmware_io.endpoints import TcpEndpoint
from firmware_io.handshake import Inspection, PathInfo, PlcHandshake
from firmware_io.plc_sim import ModbusRequestError, PlcSimError, PlcSimulator
from firmware_io.registers import (
    MAX_GLUE_POINTS,
    FeatureBit,
    GlueFrame,
    MapLayout,
    Register,
    RegisterMap,
    StatusBit,
    WordOrder,
)
from firmware_io.server import PlcLink

HIGH = RegisterMap(WordOrder.HIGH_FIRST)
#: Recipe numbers the fake controller knows, and what its "measurement" fails for each.
FAILS = {0: None, 1: FeatureBit(0), 2: FeatureBit.LENGTH | FeatureBit.TOE_HEIGHT}


def path(cycle: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(cycle)
    points = rng.uniform(-400, 400, size=(7 + cycle % 5, 3))
    normals = rng.normal(size=points.shape) + np.array([0, 0, 3.0])
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


class FakeController:
    """Publishes a known path with normals per cycle; recipe decides the tolerance verdict."""

    def __init__(self, link: PlcLink) -> None:
        self.link = link
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> FakeController:
        self.link.set_status(cameras_ok=True, calibration_ok=True)
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        while not self._stop.is_set():
            trigger = self.link.wait_trigger(timeout_s=0.05)
            if trigger is None:
                continue
            points, normals = path(trigger.cycle)
            failed = FAILS[trigger.recipe]
            self.link.publish_result(
                trigger.cycle,
                heel_height_mm=18.5,
                toe_height_mm=7.25,
                length_mm=250.0 + trigger.cycle,
                cycle_time_ms=400.0,
                glue_points=points,
                path=PathInfo(normals, GlueFrame.ROBOT_BASE, nozzle_offset_mm=1.5, glue_offset_mm=2.0),
                inspection=None if failed is None else Inspection(failed),
            )


@pytest.fixture(params=[2, 1], ids=["v2", "v1"])
def link(request: pytest.FixtureRequest) -> Iterator[PlcLink]:
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=request.param) as running, FakeController(running):
        yield running


def test_v2_carries_normals_frame_offsets_and_the_recipe_verdict() -> None:
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=2) as link, FakeController(link):
        with PlcSimulator(link.endpoint, map_version=2) as plc:  # type: ignore[arg-type]
            for recipe, expected in ((1, True), (2, False), (0, None)):
                reading = plc.run_cycle(recipe=recipe)
                assert reading.ok and reading.map_version == 2 and reading.recipe == recipe
                assert reading.in_tolerance is expected
                assert reading.feature_fails == (FAILS[recipe] or FeatureBit(0))
                points, normals = path(reading.cycle)
                np.testing.assert_array_equal(reading.glue_points, points.astype(np.float32))
                np.testing.assert_array_equal(reading.glue_normals, normals.astype(np.float32))
                assert reading.glue_frame == GlueFrame.ROBOT_BASE
                assert reading.nozzle_offset_mm == 1.5 and reading.glue_offset_mm == 2.0
            assert plc.read_header().recipe_select == 0  # kept as the PLC wrote it last


def test_v1_is_unchanged_for_plcs_programmed_for_it() -> None:
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=1) as link, FakeController(link):
        with PlcSimulator(link.endpoint, map_version=1) as plc:  # type: ignore[arg-type]
            reading = plc.run_cycle()
            assert reading.ok and reading.map_version == 1 and len(reading.glue_normals) == 0
            np.testing.assert_array_equal(reading.glue_points, path(reading.cycle)[0].astype(np.float32))
            # Version 1's reserved registers read 0, its status bits 6..15 stay clear, recipe select is refused.
            assert plc.read_registers(7, 3) == [0, 0, 0] and plc.read_registers(19, 5) == [0] * 5
            assert not reading.status & (StatusBit.IN_TOLERANCE | StatusBit.OUT_OF_TOLERANCE)
            with pytest.raises(ModbusRequestError, match="0x02"):
                plc.write_register(Register.RECIPE_SELECT, 2)
            with pytest.raises(PlcSimError, match="version 2"):
                plc.select_recipe(2)
            with pytest.raises(ModbusRequestError, match="0x02"):
                plc.read_registers(MapLayout.of(1).size, 1)


def test_a_plc_programmed_for_one_version_refuses_the_other() -> None:
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=2) as link:
        with pytest.raises(PlcSimError, match="programmed for 1"):
            PlcSimulator(link.endpoint, map_version=1).connect()  # type: ignore[arg-type]


def test_v2_writes_only_trigger_and_recipe_and_ends_at_its_size() -> None:
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=2) as link, FakeController(link):
        with PlcSimulator(link.endpoint) as plc:  # type: ignore[arg-type]
            for address in (Register.RESULT_RECIPE, Register.FEATURE_FAILS, Register.GLUE_FRAME, 100):
                with pytest.raises(ModbusRequestError, match="0x02"):
                    plc.write_register(address, 1)
            size = MapLayout.of(2).size
            assert size == 100 + 12 * MAX_GLUE_POINTS
            assert len(plc.read_registers(size - 120, 120)) == 120
            with pytest.raises(ModbusRequestError, match="0x02"):
                plc.read_registers(size - 1, 2)


def test_recipe_select_is_taken_when_the_trigger_is_accepted() -> None:
    handshake = PlcHandshake(HIGH, MapLayout.of(2))
    handshake.set_health(cameras_ok=True, calibration_ok=True)
    handshake.plc_write(Register.RECIPE_SELECT, [7])
    handshake.plc_write(Register.TRIGGER, [1])
    handshake.plc_write(Register.RECIPE_SELECT, [9])  # while busy: for the next trigger
    trigger = handshake.wait_trigger(1.0, 0.1)
    assert trigger is not None and trigger.recipe == 7
    points, normals = path(1)
    handshake.publish_result(
        1, heel_height_mm=1, toe_height_mm=1, length_mm=1, cycle_time_ms=1, glue_points=points,
        path=PathInfo(normals), inspection=Inspection(FeatureBit.HEEL_HEIGHT),
    )  # fmt: skip
    assert handshake.plc_read(Register.RESULT_RECIPE, 2) == [7, int(FeatureBit.HEEL_HEIGHT)]
    assert handshake.status & StatusBit.OUT_OF_TOLERANCE and not handshake.status & StatusBit.IN_TOLERANCE
    handshake.plc_write(Register.TRIGGER, [2])
    trigger = handshake.wait_trigger(1.0, 0.1)
    assert trigger is not None and trigger.recipe == 9
    assert not handshake.status & (StatusBit.OUT_OF_TOLERANCE | StatusBit.IN_TOLERANCE)  # cleared while busy
    with pytest.raises(ValueError, match="normals"):
        handshake.publish_result(2, heel_height_mm=1, toe_height_mm=1, length_mm=1, cycle_time_ms=1, glue_points=points)
    with pytest.raises(ValueError, match="unit vectors"):
        handshake.publish_result(
            2, heel_height_mm=1, toe_height_mm=1, length_mm=1, cycle_time_ms=1, glue_points=points,
            path=PathInfo(normals * 2),
        )  # fmt: skip


# ---- mbpoll: a Modbus master written by others -----------------------------------------------------


def mbpoll(port: int, *args: str, write: tuple[str, ...] = (), high_first: bool = True) -> dict[int, float]:
    """Run mbpoll once (0-based addresses) and parse its `[address]: value` lines; -B: high word first."""
    options = ["-m", "tcp", "-p", str(port), "-a", "1", "-0", "-1", *(["-B"] if high_first else []), "-o", "5", *args]
    command = ["mbpoll", *options, "127.0.0.1", *write]
    done = subprocess.run(command, capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stdout + done.stderr
    return {int(a): float(v) for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)", done.stdout, re.MULTILINE)}


def test_mbpoll_reads_the_v2_header_and_points(link: PlcLink) -> None:
    port = link.endpoint.port  # type: ignore[union-attr]
    version = link.layout.version
    if version == 2:
        mbpoll(port, "-t", "4", "-r", "7", write=("2",))  # mbpoll writes the recipe number
    with PlcSimulator(link.endpoint) as plc:  # type: ignore[arg-type]
        reading = plc.run_cycle()
    header = mbpoll(port, "-t", "4", "-r", "0", "-c", str(link.layout.header_size))
    assert header[Register.MAP_VERSION] == version and header[Register.RESULT_CYCLE] == reading.cycle
    assert header[Register.GLUE_POINT_COUNT] == len(reading.glue_points)
    floats = mbpoll(port, "-t", "4:float", "-r", "10", "-c", "4")
    assert floats == {10: 18.5, 12: 7.25, 14: 250.0 + reading.cycle, 16: 400.0}
    count = len(reading.glue_points)
    per_point = link.layout.registers_per_point
    values = mbpoll(port, "-t", "4:float", "-r", "100", "-c", str(count * per_point // 2))
    decoded = np.array([values[100 + 2 * k] for k in range(count * per_point // 2)]).reshape(count, -1)
    points, normals = path(reading.cycle)
    # mbpoll prints 6 significant digits: compare at that precision.
    np.testing.assert_allclose(decoded[:, :3], points, rtol=2e-6, atol=1e-3)
    if version == 2:
        status = int(header[Register.STATUS])
        assert header[Register.RESULT_RECIPE] == 2 and status & StatusBit.OUT_OF_TOLERANCE
        assert header[Register.FEATURE_FAILS] == FeatureBit.LENGTH | FeatureBit.TOE_HEIGHT
        assert header[Register.GLUE_FRAME] == GlueFrame.ROBOT_BASE
        np.testing.assert_allclose(decoded[:, 3:], normals, atol=2e-6)
        assert mbpoll(port, "-t", "4:float", "-r", "20", "-c", "2") == {20: 1.5, 22: 2.0}
    else:
        assert decoded.shape[1] == 3 and header[7] == header[8] == header[9] == 0


def test_the_plc_tag_list_names_every_register_at_its_address() -> None:
    import csv
    from pathlib import Path

    tags = Path(__file__).resolve().parents[2] / "docs" / "plc" / "tags.csv"
    with tags.open(newline="") as source:
        rows = list(csv.DictReader(source))
    addresses = {int(row["address"]) for row in rows}
    assert {int(register) for register in Register} <= addresses
    v1_only = {int(row["address"]) for row in rows if row["map_version"] == "1"}
    assert Register.RECIPE_SELECT not in v1_only and Register.GLUE_FRAME not in v1_only


def test_cellctl_plc_sim_reads_v2_with_a_recipe(capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from cellctl.cli import main

    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=2) as link, FakeController(link):
        port = str(link.endpoint.port)  # type: ignore[union-attr]
        common = ["plc-sim", "--port", port, "--cycles", "1", "--interval", "0", "--map-version", "2"]
        assert main([*common, "--recipe", "2"]) == 0
        line = capsys.readouterr().out.strip()
        assert "recipe=2 tolerance=FAIL LENGTH|TOE_HEIGHT frame=robot_base normals=" in line, line
        assert main([*common, "--recipe", "1", "--json"]) == 0
        record = json.loads(capsys.readouterr().out)
        assert record["map_version"] == 2 and record["in_tolerance"] is True and record["glue_frame"] == "robot_base"
        assert len(record["glue_normals"]) == record["glue_point_count"] and record["nozzle_offset_mm"] == 1.5
        assert main([*common, "--recipe", "70000"]) == 2  # one line, no traceback
        assert "--recipe 70000" in capsys.readouterr().err
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=1) as link, FakeController(link):
        port = str(link.endpoint.port)  # type: ignore[union-attr]
        assert main(["plc-sim", "--port", port, "--cycles", "1", "--map-version", "2"]) == 1
        assert "programmed for 2" in capsys.readouterr().err


def test_mbpoll_reads_v2_floats_in_low_word_first_order_too() -> None:
    """mbpoll's own default is the low word first ("CDAB"): a controller configured so reads right without -B."""
    with PlcLink(TcpEndpoint("127.0.0.1", 0), map_version=2, word_order=WordOrder.LOW_FIRST) as link:
        with FakeController(link), PlcSimulator(link.endpoint, word_order=WordOrder.LOW_FIRST) as plc:  # type: ignore[arg-type]
            reading = plc.run_cycle(recipe=1)
        port = link.endpoint.port  # type: ignore[union-attr]
        assert mbpoll(port, "-t", "4:float", "-r", "10", "-c", "4", high_first=False)[14] == 250.0 + reading.cycle
        values = mbpoll(port, "-t", "4:float", "-r", "100", "-c", "6", high_first=False)
        points, normals = path(reading.cycle)
        np.testing.assert_allclose(
            [values[100 + 2 * k] for k in range(6)], np.hstack([points[0], normals[0]]), rtol=2e-6, atol=1e-3
        )
