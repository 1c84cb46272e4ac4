"""PlcLink over real Modbus TCP on 127.0.0.1 (and RTU through a pty pair), driven by the PLC simulator.

Every test serves on its own port (bound as port 0) and runs a fake controller thread that publishes
a deterministic "truth" per cycle, so what the PLC reads can be compared value by value.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import struct
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient
from pymodbus.constants import ExcCodes

from cellctl.cli import plc_sim as plc_sim_command
from firmware_io.endpoints import SerialEndpoint, TcpEndpoint
from firmware_io.plc_sim import (
    CycleReading,
    HeartbeatLost,
    ModbusRequestError,
    PlcSimError,
    PlcSimulator,
    TriggerRefused,
)
from firmware_io.registers import MAP_SIZE, ErrorCode, Register, RegisterMap, StatusBit, WordOrder
from firmware_io.server import PlcLink

LOCALHOST = "127.0.0.1"


class FakeController:
    """Stands in for the daemon: waits for triggers and publishes a known result per cycle."""

    def __init__(self, link: PlcLink) -> None:
        self.link = link
        self.error_cycles: dict[int, ErrorCode] = {}
        self.hold = threading.Event()  # cleared: cycles wait in BUSY until released
        self.hold.set()
        self.started: list[int] = []
        self.cycle_started = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake controller", daemon=True)

    @staticmethod
    def truth(cycle: int) -> dict:
        rng = np.random.default_rng(cycle)
        return {
            "heel_height_mm": 20.0 + cycle * 0.125,
            "toe_height_mm": 8.0 + cycle * 0.0625,
            "length_mm": 250.0 + cycle,
            "cycle_time_ms": 400.0 + cycle,
            "glue_points": rng.uniform(-300, 300, size=(5 + cycle % 7, 3)),
        }

    def __enter__(self) -> FakeController:
        self.link.set_status(cameras_ok=True, calibration_ok=True)
        self._thread.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        self.hold.set()
        self._thread.join(5)
        assert not self._thread.is_alive()

    def _run(self) -> None:
        while not self._stop.is_set():
            trigger = self.link.wait_trigger(timeout_s=0.05)
            if trigger is None:
                continue
            self.started.append(trigger.cycle)
            self.cycle_started.set()
            self.hold.wait()
            if trigger.cycle in self.error_cycles:
                self.link.publish_error(trigger.cycle, self.error_cycles[trigger.cycle], cycle_time_ms=12.5)
            else:
                self.link.publish_result(trigger.cycle, **self.truth(trigger.cycle))


@pytest.fixture
def link() -> Iterator[PlcLink]:
    with PlcLink(TcpEndpoint(LOCALHOST, 0), heartbeat_period_s=0.1) as started:
        yield started


@pytest.fixture
def controller(link: PlcLink) -> Iterator[FakeController]:
    with FakeController(link) as fake:
        yield fake


def simulator(link: PlcLink, **kwargs: object) -> PlcSimulator:
    return PlcSimulator(link.endpoint, response_timeout_s=1.0, **kwargs)  # type: ignore[arg-type]


def assert_matches_truth(reading: CycleReading) -> None:
    truth = FakeController.truth(reading.cycle)
    assert reading.ok
    for name in ("heel_height_mm", "toe_height_mm", "length_mm", "cycle_time_ms"):
        assert getattr(reading, name) == np.float32(truth[name]), name
    np.testing.assert_array_equal(reading.glue_points, truth["glue_points"].astype(np.float32))


# ---- handshake -------------------------------------------------------------------------------------


def test_several_cycles_deliver_exactly_what_the_controller_published(
    link: PlcLink, controller: FakeController
) -> None:
    with simulator(link) as plc:
        readings = [plc.run_cycle(timeout_s=3.0) for _ in range(6)]
    assert [r.cycle for r in readings] == [1, 2, 3, 4, 5, 6]
    assert controller.started == [1, 2, 3, 4, 5, 6]
    for reading in readings:
        assert_matches_truth(reading)
        assert reading.status & StatusBit.READY and not reading.status & (StatusBit.BUSY | StatusBit.ERROR)


def test_state_switches_to_busy_before_the_trigger_is_acknowledged(link: PlcLink, controller: FakeController) -> None:
    with simulator(link) as plc:
        plc.run_cycle(timeout_s=3.0)
        controller.hold.clear()
        plc.trigger(2)
        header = plc.read_header()  # first read after the write ack
        assert header.status & StatusBit.BUSY
        assert not header.status & (StatusBit.READY | StatusBit.RESULT_VALID | StatusBit.ERROR)
        assert header.result_cycle == 0 and header.glue_point_count == 0
        assert np.isnan(header.heel_height_mm)
        controller.hold.set()
        assert_matches_truth(plc.wait_result(2, timeout_s=3.0))


def test_error_cycle_reports_code_and_next_cycle_recovers(link: PlcLink, controller: FakeController) -> None:
    controller.error_cycles[2] = ErrorCode.NO_SOLE
    with simulator(link) as plc:
        plc.run_cycle(timeout_s=3.0)
        failed = plc.run_cycle(timeout_s=3.0)
        recovered = plc.run_cycle(timeout_s=3.0)
    assert not failed.ok and failed.error_code == ErrorCode.NO_SOLE
    assert failed.status & StatusBit.ERROR and not failed.status & StatusBit.RESULT_VALID
    assert np.isnan(failed.heel_height_mm) and failed.cycle_time_ms == 12.5 and len(failed.glue_points) == 0
    assert_matches_truth(recovered)
    assert not recovered.status & StatusBit.ERROR


@pytest.mark.parametrize("word_order", list(WordOrder))
def test_float32_word_order_on_the_wire(word_order: WordOrder) -> None:
    with PlcLink(TcpEndpoint(LOCALHOST, 0), word_order=word_order) as link, FakeController(link):
        with simulator(link, word_order=word_order) as plc:
            reading = plc.run_cycle(timeout_s=3.0)
            raw = plc.read_registers(Register.LENGTH_MM, 2)
    assert_matches_truth(reading)
    # length of cycle 1 is 251.0 = 0x437B0000
    assert raw == ([0x437B, 0x0000] if word_order is WordOrder.HIGH_FIRST else [0x0000, 0x437B])


def test_full_glue_path_round_trips(link: PlcLink) -> None:
    points = np.random.default_rng(2000).uniform(-500, 500, size=(2000, 3))
    link.set_status(cameras_ok=True, calibration_ok=True)
    with simulator(link) as plc:
        plc.trigger(1)
        trigger = link.wait_trigger(timeout_s=2.0)
        assert trigger is not None and trigger.cycle == 1
        link.publish_result(1, heel_height_mm=1, toe_height_mm=2, length_mm=3, cycle_time_ms=4, glue_points=points)
        reading = plc.wait_result(1, timeout_s=3.0)
        last_register = plc.read_registers(MAP_SIZE - 1, 1)
    np.testing.assert_array_equal(reading.glue_points, points.astype(np.float32))
    assert last_register == RegisterMap().encode_floats([points[-1, 2]])[1:]  # low word of the last z


# ---- refused and malformed requests --------------------------------------------------------------------


@pytest.mark.parametrize("address", [0, 1, 3, 4, 5, 6, 7, 10, 17, 18, 50, 100, MAP_SIZE - 1])
def test_writes_to_read_only_registers_are_refused(link: PlcLink, address: int) -> None:
    with simulator(link) as plc:
        before = plc.read_registers(0, 19)
        with pytest.raises(ModbusRequestError) as refused:
            plc.write_register(address, 1234)
        assert refused.value.exception_code == ExcCodes.ILLEGAL_ADDRESS
        after = plc.read_registers(0, 19)
    assert after[1:] == before[1:]  # the heartbeat (0) may have advanced


def test_multi_register_write_covering_the_trigger_is_refused_whole(link: PlcLink, controller: FakeController) -> None:
    with simulator(link) as plc:
        for address, values in [(2, [9, 9]), (1, [0, 9]), (0, [0, 0, 9])]:
            with pytest.raises(ModbusRequestError) as refused:
                plc.write_registers(address, values)
            assert refused.value.exception_code == ExcCodes.ILLEGAL_ADDRESS
        assert plc.read_header().trigger == 0
        plc.write_registers(Register.TRIGGER, [1])  # fc 16 on the trigger alone is fine
        assert_matches_truth(plc.wait_result(1, timeout_s=3.0))
    assert controller.started == [1]


def test_out_of_range_addresses_and_foreign_functions_are_refused(link: PlcLink) -> None:
    with simulator(link) as plc:
        for address, count in [(MAP_SIZE, 1), (MAP_SIZE - 2, 3), (40000, 10), (65535, 1)]:
            with pytest.raises(ModbusRequestError) as refused:
                plc.read_registers(address, count)
            assert refused.value.exception_code == ExcCodes.ILLEGAL_ADDRESS
        with pytest.raises(ModbusRequestError) as refused:
            plc.write_register(MAP_SIZE + 5, 1)
        assert refused.value.exception_code == ExcCodes.ILLEGAL_ADDRESS
        assert len(plc.read_registers(MAP_SIZE - 125, 125)) == 125
    client = ModbusTcpClient(LOCALHOST, port=link.endpoint.port, timeout=1.0, retries=0)
    try:
        assert client.connect()
        assert client.read_coils(0, count=8, device_id=1).exception_code == ExcCodes.ILLEGAL_FUNCTION
        assert client.read_input_registers(0, count=2, device_id=1).exception_code == ExcCodes.ILLEGAL_FUNCTION
        assert client.write_coil(2, True, device_id=1).exception_code == ExcCodes.ILLEGAL_FUNCTION
        assert client.read_holding_registers(0, count=2, device_id=7).exception_code == ExcCodes.GATEWAY_NO_RESPONSE
        assert client.read_holding_registers(6, count=1, device_id=1).registers == [1]  # still served
    finally:
        client.close()


def test_unit_id_zero_answers_any_unit_on_tcp() -> None:
    with PlcLink(TcpEndpoint(LOCALHOST, 0), unit_id=0) as link:
        for unit in (1, 7, 255):
            with simulator(link, unit_id=unit) as plc:
                assert plc.read_header().map_version == 1


def raw_request(port: int, payload: bytes) -> bytes:
    """Send raw bytes as one Modbus TCP client and return whatever comes back within 1 s."""
    with socket.create_connection((LOCALHOST, port), timeout=1.0) as raw:
        raw.sendall(payload)
        try:
            return raw.recv(260)
        except TimeoutError:
            return b""


def mbap(pdu: bytes, unit: int = 1, transaction: int = 0x1234) -> bytes:
    return struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu


def test_malformed_frames_get_an_exception_and_do_not_disturb_the_server(
    link: PlcLink, controller: FakeController
) -> None:
    port = link.endpoint.port
    with simulator(link) as plc:
        plc.run_cycle(timeout_s=3.0)
        for pdu, code in [
            (struct.pack(">BHH", 3, 0, 0), ExcCodes.ILLEGAL_VALUE),  # count 0
            (struct.pack(">BHH", 3, 0, 200), ExcCodes.ILLEGAL_VALUE),  # count above 125
            (bytes([0x63, 0, 0]), ExcCodes.ILLEGAL_FUNCTION),
            (bytes([6, 0]), ExcCodes.ILLEGAL_VALUE),  # truncated PDU
        ]:
            answer = raw_request(port, mbap(pdu))
            assert answer[7] == pdu[0] | 0x80 and answer[8] == code, (pdu.hex(), answer.hex())
        assert raw_request(port, b"\x00\x01\x00") == b""  # truncated header: nothing to answer
        with socket.create_connection((LOCALHOST, port), timeout=1.0) as dropped:
            dropped.sendall(mbap(struct.pack(">BHH", 3, 0, 19))[:9])  # half a request, then gone
        assert_matches_truth(plc.run_cycle(timeout_s=3.0))


# ---- trigger while busy -----------------------------------------------------------------------------


def test_trigger_while_busy_is_refused_and_the_running_cycle_completes(
    link: PlcLink, controller: FakeController
) -> None:
    controller.hold.clear()
    with simulator(link) as plc:
        plc.trigger(1)
        assert controller.cycle_started.wait(2.0)
        with pytest.raises(TriggerRefused):
            plc.trigger(2)
        plc.trigger(1)  # the running cycle's own number again: acknowledged, starts nothing
        header = plc.read_header()
        assert header.trigger == 1 and header.refused_triggers == 1 and header.status & StatusBit.BUSY
        controller.hold.set()
        assert_matches_truth(plc.wait_result(1, timeout_s=3.0))
        assert_matches_truth(plc.run_cycle(2, timeout_s=3.0))
    assert controller.started == [1, 2]


# ---- connections ------------------------------------------------------------------------------------


def test_plc_disconnect_mid_cycle_and_reconnect_finds_the_result(link: PlcLink, controller: FakeController) -> None:
    controller.hold.clear()
    first = simulator(link)
    first.connect()
    first.trigger(1)
    assert controller.cycle_started.wait(2.0)
    first.close()
    controller.hold.set()
    with simulator(link) as second:  # a new TCP connection, as after a PLC restart
        assert second.next_cycle_number() == 2
        assert_matches_truth(second.wait_result(1, timeout_s=3.0))
        assert_matches_truth(second.run_cycle(timeout_s=3.0))


def test_two_connections_are_served_side_by_side(link: PlcLink, controller: FakeController) -> None:
    with simulator(link) as plc, simulator(link) as diagnostics:
        plc.run_cycle(timeout_s=3.0)
        assert diagnostics.read_header().result_cycle == 1
        diagnostics.close()
        assert_matches_truth(plc.run_cycle(timeout_s=3.0))


def test_heartbeat_advances_and_the_watchdog_accepts_it(link: PlcLink, controller: FakeController) -> None:
    with simulator(link, heartbeat_limit_s=0.6) as plc:
        first = plc.read_header().heartbeat
        plc.watch_heartbeat(1.0)
        assert (plc.read_header().heartbeat - first) % 0x10000 >= 3  # 0.1 s period, > 1 s elapsed


def test_heartbeat_stops_when_the_controller_hangs_and_the_watchdog_fires() -> None:
    # No controller calls at all: after the liveness timeout the heartbeat must freeze.
    with PlcLink(TcpEndpoint(LOCALHOST, 0), heartbeat_period_s=0.05, liveness_timeout_s=0.2) as link:
        with simulator(link, heartbeat_limit_s=0.4) as plc:
            with pytest.raises(HeartbeatLost, match="heartbeat stuck"):
                plc.watch_heartbeat(3.0)


# ---- lifetime ---------------------------------------------------------------------------------------


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def test_start_stop_leaves_no_threads_sockets_or_listeners() -> None:
    threads_before, fds_before = threading.active_count(), open_fds()
    link = PlcLink(TcpEndpoint(LOCALHOST, 0))
    link.start()
    port = link.endpoint.port
    client = ModbusTcpClient(LOCALHOST, port=port, timeout=1.0, retries=0)
    assert client.connect()
    assert client.read_holding_registers(6, count=1, device_id=1).registers == [1]
    link.stop()  # with the client still connected
    client.close()
    assert threading.active_count() == threads_before
    assert open_fds() == fds_before
    with pytest.raises(OSError):
        socket.create_connection((LOCALHOST, port), timeout=1.0).close()
    with PlcLink(TcpEndpoint(LOCALHOST, port)) as again:  # the same port is free again at once
        assert again.endpoint.port == port
    assert threading.active_count() == threads_before


def test_start_fails_clearly_when_the_port_is_taken() -> None:
    with socket.socket() as taken:
        taken.bind((LOCALHOST, 0))
        taken.listen()
        link = PlcLink(TcpEndpoint(LOCALHOST, taken.getsockname()[1]))
        with pytest.raises(RuntimeError, match="cannot serve Modbus on tcp://127.0.0.1:.*port already in use"):
            link.start()
        link.stop()


def test_wait_trigger_returns_none_once_the_link_stops() -> None:
    link = PlcLink(TcpEndpoint(LOCALHOST, 0))
    link.start()
    result: list[object] = []
    waiter = threading.Thread(target=lambda: result.append(link.wait_trigger(timeout_s=None)))
    waiter.start()
    time.sleep(0.05)
    link.stop()
    waiter.join(2.0)
    assert not waiter.is_alive() and result == [None]


# ---- cellctl plc-sim -------------------------------------------------------------------------------


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="cellctl")
    plc_sim_command.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_prints_one_line_per_cycle(
    link: PlcLink, controller: FakeController, capsys: pytest.CaptureFixture
) -> None:
    controller.error_cycles[2] = ErrorCode.SOLE_AT_BORDER
    port = str(link.endpoint.port)
    assert run_cli(["plc-sim", "--port", port, "--cycles", "3", "--interval", "0.05"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3
    assert lines[0].startswith("cycle 1: ok heel=20.12 mm toe=8.06 mm length=251.00 mm points=6")
    assert lines[1].startswith("cycle 2: error 31 SOLE_AT_BORDER (The sole touches the image border")
    assert lines[2].startswith("cycle 3: ok")

    assert run_cli(["plc-sim", "--port", port, "--cycles", "2", "--interval", "0", "--json"]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["cycle"] for r in records] == [4, 5]
    truth = FakeController.truth(4)
    assert records[0]["ok"] and records[0]["length_mm"] == truth["length_mm"]
    np.testing.assert_allclose(records[0]["glue_points"], truth["glue_points"], atol=1e-3)


def test_cli_fails_when_no_controller_answers(capsys: pytest.CaptureFixture) -> None:
    with socket.socket() as probe:
        probe.bind((LOCALHOST, 0))
        free_port = probe.getsockname()[1]
    assert run_cli(["plc-sim", "--port", str(free_port), "--cycles", "1"]) == 1
    assert "cannot connect to the controller at tcp://127.0.0.1" in capsys.readouterr().err


def test_cli_rejects_bad_options() -> None:
    with pytest.raises(ValueError, match="--cycles 0"):
        run_cli(["plc-sim", "--cycles", "0"])


# ---- Modbus RTU through a pseudo-terminal pair ------------------------------------------------------


class PtyNullModem:
    """A serial cable between two pseudo-terminals, without socat, that can be unplugged and replugged.

    One os.openpty() pair cannot serve both ends: its master side has no device name for pyserial
    to open. So each end gets its own pty and a thread copies bytes between the two masters. The
    controller end is reached through a symlink, like the /dev/serial/by-id/... names udev gives
    USB adapters, so a replugged "adapter" (a new pty) appears under the same name.
    """

    def __init__(self, directory: Path) -> None:
        self.controller_port = str(directory / "ttyCELL")
        self._lock = threading.Lock()
        self._plc = self._open_pty()
        self.plc_port = os.ttyname(self._plc[1])
        self._cell: tuple[int, int] | None = None
        self.replug()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._copy, name="pty null modem", daemon=True)
        self._thread.start()

    @staticmethod
    def _open_pty() -> tuple[int, int]:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo or line editing before pyserial configures the port
        return master, slave

    def unplug(self) -> None:
        with self._lock:
            if self._cell is not None:
                for fd in self._cell:
                    os.close(fd)
                self._cell = None

    def replug(self) -> None:
        self.unplug()
        with self._lock:
            self._cell = self._open_pty()
            link = self.controller_port + ".new"
            os.symlink(os.ttyname(self._cell[1]), link)
            os.replace(link, self.controller_port)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.unplug()
        for fd in self._plc:
            os.close(fd)

    def _copy(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                if self._cell is None:
                    masters = [self._plc[0]]
                else:
                    masters = [self._plc[0], self._cell[0]]
                readable, _, _ = select.select(masters, [], [], 0.02)
                for fd in readable:
                    data = os.read(fd, 4096)
                    if fd == self._plc[0] and self._cell is not None:
                        os.write(self._cell[0], data)
                    elif fd != self._plc[0]:
                        os.write(self._plc[0], data)


@pytest.fixture
def null_modem(tmp_path: Path) -> Iterator[PtyNullModem]:
    cable = PtyNullModem(tmp_path)
    try:
        yield cable
    finally:
        cable.close()


def rtu_endpoints(cable: PtyNullModem) -> tuple[SerialEndpoint, SerialEndpoint]:
    # parity "N": Linux ptys refuse PARENB (EINVAL); the 8E1 default is for real RS-485 adapters.
    return (
        SerialEndpoint(cable.controller_port, baudrate=115200, parity="N"),
        SerialEndpoint(cable.plc_port, baudrate=115200, parity="N"),
    )


def test_rtu_slave_over_a_serial_line(null_modem: PtyNullModem) -> None:
    controller_side, plc_side = rtu_endpoints(null_modem)
    threads_before = threading.active_count()
    with PlcLink(controller_side, unit_id=3) as link, FakeController(link):
        with PlcSimulator(plc_side, unit_id=3, response_timeout_s=1.0) as plc:
            for _ in range(3):
                assert_matches_truth(plc.run_cycle(timeout_s=3.0))
            with pytest.raises(ModbusRequestError) as refused:
                plc.write_register(Register.RESULT_CYCLE, 1)
            assert refused.value.exception_code == ExcCodes.ILLEGAL_ADDRESS
        # A request for another slave on the bus must get no answer at all.
        other_slave = PlcSimulator(plc_side, unit_id=4, response_timeout_s=0.3)
        try:
            with pytest.raises(PlcSimError, match="no answer"):
                other_slave.connect()
        finally:
            other_slave.close()
        with PlcSimulator(plc_side, unit_id=3, response_timeout_s=1.0) as plc:  # the line still works
            assert_matches_truth(plc.run_cycle(timeout_s=3.0))
    assert threading.active_count() == threads_before


def test_rtu_line_comes_back_after_the_adapter_is_replugged(null_modem: PtyNullModem) -> None:
    controller_side, plc_side = rtu_endpoints(null_modem)
    with PlcLink(controller_side) as link, FakeController(link):
        with PlcSimulator(plc_side, response_timeout_s=0.5) as plc:
            assert_matches_truth(plc.run_cycle(timeout_s=3.0))
            null_modem.unplug()
            with pytest.raises(PlcSimError, match="no answer"):
                plc.read_header()
            null_modem.replug()
            deadline = time.monotonic() + 5.0
            while True:  # the link retries the port every second
                try:
                    plc.read_header()
                    break
                except PlcSimError:
                    assert time.monotonic() < deadline, "the RTU line did not come back after replugging"
            assert_matches_truth(plc.run_cycle(timeout_s=3.0))


def test_rtu_start_fails_clearly_without_the_serial_port(tmp_path: Path) -> None:
    link = PlcLink(SerialEndpoint(str(tmp_path / "ttyUSB9")))
    with pytest.raises(
        RuntimeError, match="cannot serve Modbus on rtu:.*ttyUSB9 19200 8E1.*does the serial port exist"
    ):
        link.start()
    link.stop()
