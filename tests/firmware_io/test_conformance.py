"""Conformance with a Modbus master nobody here wrote: Debian's mbpoll (libmodbus), over TCP and over RTU
through a socat pty pair (8N1). Installed by the Makefile's APT_PACKAGES (mbpoll, socat).

Each test runs a whole trigger/result cycle as a PLC would (write the trigger, poll the result cycle, read
the measurement as float32 and the glue points) and the documented exceptions, parsed from mbpoll's output.
"""

from __future__ import annotations

import re
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from firmware_io.endpoints import SerialEndpoint, TcpEndpoint
from firmware_io.registers import Register
from firmware_io.server import PlcLink
from tests.firmware_io.test_modbus import FakeController

VALUE = re.compile(r"^\[(\d+)\]:\s+(\S+)", re.MULTILINE)  # 32768 and up print as "32768 (-32768)"


class Mbpoll:
    """mbpoll with PDU (0-based) addresses, one request per call."""

    def __init__(self, target: list[str], device: str) -> None:
        self.target, self.device = target, device

    def call(self, *options: str, values: tuple[int, ...] = ()) -> subprocess.CompletedProcess[str]:
        argv = ["mbpoll", *self.target, "-0", "-1", "-o", "1", *options, self.device, *map(str, values)]
        return subprocess.run(argv, capture_output=True, text=True, timeout=30)

    def read(self, address: int, count: int = 1, kind: str = "4", unit: int | None = None) -> list[float]:
        unit_option = () if unit is None else ("-a", str(unit))
        order = ("-B",) if "float" in kind else ()  # high word first, the map's default word order
        result = self.call("-r", str(address), "-c", str(count), "-t", kind, *order, *unit_option)
        assert result.returncode == 0, result.stderr
        return [float(v) for _, v in VALUE.findall(result.stdout)]

    def write(self, address: int, value: int) -> None:
        result = self.call("-r", str(address), values=(value,))
        assert result.returncode == 0, result.stderr

    def refusal(self, *options: str, values: tuple[int, ...] = ()) -> str:
        """The error line of a request that must fail."""
        result = self.call(*options, values=values)
        assert result.returncode != 0, result.stdout
        return result.stderr.strip()


def full_cycle(master: Mbpoll, controller: FakeController, cycle: int) -> None:
    master.write(Register.TRIGGER, cycle)
    deadline = time.monotonic() + 10
    while master.read(Register.RESULT_CYCLE)[0] != cycle:
        assert time.monotonic() < deadline, "no result"
    truth = FakeController.truth(cycle)
    header = master.read(0, 19)
    assert header[Register.TRIGGER] == cycle and int(header[Register.STATUS]) & 0b0110 == 0b0100  # RESULT_VALID
    floats = master.read(Register.HEEL_HEIGHT_MM, 4, "4:float")
    names = ("heel_height_mm", "toe_height_mm", "length_mm", "cycle_time_ms")
    # mbpoll prints floats with 6 significant digits
    assert floats == pytest.approx([float(np.float32(truth[n])) for n in names], rel=1e-5)
    count = int(header[Register.GLUE_POINT_COUNT])
    points = master.read(Register.GLUE_POINTS, 3 * count, "4:float")
    np.testing.assert_allclose(np.reshape(points, (-1, 3)), truth["glue_points"].astype(np.float32), rtol=1e-5)


def documented_exceptions(master: Mbpoll, controller: FakeController, cycle: int) -> None:
    assert "Illegal data address" in master.refusal("-r", str(Register.RESULT_CYCLE), values=(7,))
    assert "Illegal data address" in master.refusal("-r", "12100")
    assert "Illegal data address" in master.refusal("-r", "12090", "-c", "20")
    assert "Illegal function" in master.refusal("-t", "3")  # input registers
    assert "Illegal function" in master.refusal("-t", "0")  # coils
    controller.hold.clear()
    master.write(Register.TRIGGER, cycle)
    assert controller.cycle_started.wait(5)
    assert "busy" in master.refusal("-r", str(Register.TRIGGER), values=(cycle + 1,))
    master.write(Register.TRIGGER, cycle)  # the running cycle's number again: acknowledged, starts nothing
    controller.hold.set()
    deadline = time.monotonic() + 10
    while master.read(Register.RESULT_CYCLE)[0] != cycle:
        assert time.monotonic() < deadline
    assert controller.started[-1] == cycle and controller.started.count(cycle) == 1


@pytest.fixture
def tcp_link() -> Iterator[tuple[PlcLink, FakeController]]:
    with PlcLink(TcpEndpoint("127.0.0.1", 0)) as link, FakeController(link) as controller:
        yield link, controller


def test_mbpoll_over_tcp(tcp_link: tuple[PlcLink, FakeController]) -> None:
    link, controller = tcp_link
    master = Mbpoll(["-m", "tcp", "-p", str(link.endpoint.port)], "127.0.0.1")  # type: ignore[union-attr]
    full_cycle(master, controller, 1)
    documented_exceptions(master, controller, 2)
    assert "Target device failed to respond" in master.refusal("-a", "7")  # another unit id: 0x0B
    full_cycle(master, controller, 3)


@pytest.fixture
def socat_pair(tmp_path: Path) -> Iterator[tuple[str, str]]:
    cell, plc = tmp_path / "ttyCELL", tmp_path / "ttyPLC"
    socat = subprocess.Popen(
        ["socat", f"pty,raw,echo=0,link={cell}", f"pty,raw,echo=0,link={plc}"],
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 10
        while not (cell.exists() and plc.exists()):
            assert socat.poll() is None and time.monotonic() < deadline, "socat did not create the pty pair"
            time.sleep(0.02)
        yield str(cell), str(plc)
    finally:
        socat.terminate()
        socat.wait(5)


def test_mbpoll_over_rtu(socat_pair: tuple[str, str]) -> None:
    cell, plc = socat_pair
    with PlcLink(SerialEndpoint(cell, 115200, parity="N"), unit_id=3) as link, FakeController(link) as controller:
        master = Mbpoll(["-m", "rtu", "-b", "115200", "-P", "none", "-d", "8", "-s", "1", "-a", "3"], plc)
        full_cycle(master, controller, 1)
        documented_exceptions(master, controller, 2)
        silent = master.call("-r", "0", "-a", "4")  # another slave on the bus: no answer at all
        assert silent.returncode != 0 and "timed out" in silent.stderr.lower(), silent.stderr
        full_cycle(master, controller, 3)
