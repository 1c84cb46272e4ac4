"""The link under hostile and careless traffic (issue 15): what is refused, what is closed, what is answered.

Raw sockets play the careless master, the PLC simulator (pymodbus' client) the real one.
"""

from __future__ import annotations

import random
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from pymodbus.constants import ExcCodes

from firmware_io import rtu
from firmware_io.endpoints import SerialEndpoint, TcpEndpoint
from firmware_io.plc_sim import PlcSimulator
from firmware_io.registers import MAP_SIZE, ErrorCode, Register, StatusBit
from firmware_io.server import PlcLink
from firmware_io.tcp import ConnectionLimits
from tests.firmware_io.test_modbus import PtyNullModem

LOCALHOST = "127.0.0.1"


def mbap(pdu: bytes, unit: int = 1, transaction: int = 0x1234) -> bytes:
    return struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu


def read_reply(conn: socket.socket) -> bytes:
    """One MBAP reply, or b"" when the server closed the connection."""
    try:
        return _read_reply(conn)
    except ConnectionResetError:
        return b""


def _read_reply(conn: socket.socket) -> bytes:
    header = b""
    while len(header) < 7:
        chunk = conn.recv(7 - len(header))
        if not chunk:
            return b""
        header += chunk
    length = struct.unpack(">H", header[4:6])[0]
    body = b""
    while len(body) < length - 1:
        chunk = conn.recv(length - 1 - len(body))
        if not chunk:
            return b""
        body += chunk
    return header + body


def closed_by_server(conn: socket.socket) -> bool:
    try:
        return conn.recv(1) == b""
    except ConnectionResetError:
        return True


@pytest.fixture
def link() -> Iterator[PlcLink]:
    with PlcLink(TcpEndpoint(LOCALHOST, 0), heartbeat_period_s=0.05) as started:
        started.set_status(cameras_ok=True, calibration_ok=True)
        yield started


def connect(link: PlcLink) -> socket.socket:
    return socket.create_connection((LOCALHOST, link.endpoint.port), timeout=2.0)  # type: ignore[union-attr]


# ---- finding 2: a refused request changes nothing ------------------------------------------------


def test_read_write_refused_for_its_read_range_starts_no_cycle(link: PlcLink) -> None:
    # fc 23: write trigger 7, read 2 registers at 12100 (beyond the map)
    pdu = struct.pack(">BHHHHBH", 23, MAP_SIZE, 2, Register.TRIGGER, 1, 2, 7)
    with connect(link) as conn:
        conn.sendall(mbap(pdu))
        reply = read_reply(conn)
    assert reply[7:] == bytes([23 | 0x80, ExcCodes.ILLEGAL_ADDRESS])
    assert link.wait_trigger(timeout_s=0.3) is None
    assert not link.status & StatusBit.BUSY


def test_read_write_with_a_good_read_starts_the_cycle_and_reads_after_the_write(link: PlcLink) -> None:
    pdu = struct.pack(">BHHHHBH", 23, 0, 4, Register.TRIGGER, 1, 2, 7)
    with connect(link) as conn:
        conn.sendall(mbap(pdu))
        reply = read_reply(conn)
    registers = struct.unpack(">4H", reply[9:])
    assert reply[7:9] == bytes([23, 8]) and registers[Register.TRIGGER] == 7
    assert registers[Register.STATUS] & StatusBit.BUSY  # the read saw the write's effect
    trigger = link.wait_trigger(timeout_s=2.0)
    assert trigger is not None and trigger.cycle == 7


# ---- finding 4: bad frames close at once; pipelining ------------------------------------------------


@pytest.mark.parametrize(
    "bad",
    [
        struct.pack(">HHHB", 1, 7, 6, 1) + bytes([3, 0, 0, 0, 1]),  # protocol id 7
        struct.pack(">HHHB", 1, 0, 0, 1),  # MBAP length 0
        struct.pack(">HHHB", 1, 0, 400, 1),  # MBAP length beyond 254
        b"\xff\xfe\xfd",  # garbage, then a good request in the same segment
    ],
    ids=["protocol-id", "length-0", "length-400", "garbage"],
)
def test_a_malformed_frame_closes_its_connection_and_the_next_connection_is_answered(link: PlcLink, bad: bytes) -> None:
    read_version = mbap(struct.pack(">BHH", 3, Register.MAP_VERSION, 1))
    with connect(link) as conn:
        conn.sendall(bad + read_version)
        assert closed_by_server(conn)
    with connect(link) as conn:
        conn.sendall(read_version)
        assert read_reply(conn)[9:] == b"\x00\x01"


def test_pipelined_requests_are_answered_in_order(link: PlcLink) -> None:
    requests = b"".join(mbap(struct.pack(">BHH", 3, Register.MAP_VERSION, 1), transaction=t) for t in range(1, 6))
    with connect(link) as conn:
        conn.sendall(requests)  # five requests in one segment
        replies = [read_reply(conn) for _ in range(5)]
    assert [struct.unpack(">H", r[:2])[0] for r in replies] == [1, 2, 3, 4, 5]
    assert all(r[9:] == b"\x00\x01" for r in replies)


def test_an_exception_keeps_the_connection_usable(link: PlcLink) -> None:
    with connect(link) as conn:
        conn.sendall(mbap(bytes([3, 0])))  # truncated PDU inside a well-framed request
        assert read_reply(conn)[7:] == bytes([0x83, ExcCodes.ILLEGAL_VALUE])
        conn.sendall(mbap(struct.pack(">BHH", 3, Register.MAP_VERSION, 1)))
        assert read_reply(conn)[9:] == b"\x00\x01"


# ---- finding 5: exactly the documented function codes -----------------------------------------------


@pytest.mark.parametrize("function", [1, 2, 4, 5, 7, 8, 11, 12, 15, 17, 20, 21, 22, 24, 43, 100, 129, 200, 255])
def test_undocumented_function_codes_get_illegal_function(link: PlcLink, function: int) -> None:
    with connect(link) as conn:
        conn.sendall(mbap(bytes([function, 0, 0, 0, 1])))
        reply = read_reply(conn)
    assert reply[7:] == bytes([(function | 0x80) & 0xFF, ExcCodes.ILLEGAL_FUNCTION])
    assert b"pymodbus" not in reply.lower()


# ---- finding 3: connection cap, idle timeout, allow-list ------------------------------------------


def test_idle_connections_cannot_lock_the_plc_out() -> None:
    limits = ConnectionLimits(max_connections=4, idle_timeout_s=30.0)
    with PlcLink(TcpEndpoint(LOCALHOST, 0), limits=limits) as link:
        hogs = [connect(link) for _ in range(12)]  # three times the cap, all idle
        try:
            with PlcSimulator(link.endpoint, response_timeout_s=1.0) as plc:  # the PLC reconnecting
                assert plc.read_header().map_version == 1
                assert link.connected_clients <= 4
        finally:
            for hog in hogs:
                hog.close()


def test_idle_connections_are_closed_after_the_idle_timeout() -> None:
    with PlcLink(TcpEndpoint(LOCALHOST, 0), limits=ConnectionLimits(idle_timeout_s=0.2)) as link:
        with connect(link) as conn:
            conn.settimeout(5.0)
            assert closed_by_server(conn)


def test_clients_outside_the_allow_list_are_closed_on_accept() -> None:
    for allowed, served in [(("192.0.2.0/24",), False), (("127.0.0.1",), True)]:
        with PlcLink(TcpEndpoint(LOCALHOST, 0), limits=ConnectionLimits(allowed_clients=allowed)) as link:
            with connect(link) as conn:
                conn.sendall(mbap(struct.pack(">BHH", 3, Register.MAP_VERSION, 1)))
                assert bool(read_reply(conn)) is served


def test_bad_allow_list_entry_is_named() -> None:
    with pytest.raises(ValueError, match="'plc-1' is not an IP address"):
        ConnectionLimits(allowed_clients=("plc-1",))


# ---- finding 1: the heartbeat during a long cycle, and the cycle timeout ---------------------------


def test_heartbeat_keeps_moving_during_a_slow_cycle_and_an_overrun_gets_its_own_code() -> None:
    with PlcLink(
        TcpEndpoint(LOCALHOST, 0), heartbeat_period_s=0.05, liveness_timeout_s=0.3, cycle_timeout_s=1.5
    ) as link:
        link.set_status(cameras_ok=True, calibration_ok=True)
        with PlcSimulator(link.endpoint, response_timeout_s=1.0, heartbeat_limit_s=0.4) as plc:
            plc.trigger(1)
            trigger = link.wait_trigger(timeout_s=2.0)
            assert trigger is not None
            # The controller is now busy (no PlcLink calls) for longer than the liveness timeout:
            plc.watch_heartbeat(1.0)  # raises HeartbeatLost if register 0 stops for 0.4 s
            reading = plc.wait_result(1, timeout_s=3.0)
            assert reading.error_code == ErrorCode.CYCLE_TIMEOUT and reading.status & StatusBit.ERROR
            assert reading.cycle_time_ms >= 1500
            # The late result is dropped, not published over the timeout's answer.
            assert not link.publish_result(
                1, heel_height_mm=1, toe_height_mm=1, length_mm=1, cycle_time_ms=1, glue_points=[]
            )
            assert plc.read_header().error_code == ErrorCode.CYCLE_TIMEOUT


def test_last_cycle_from_before_a_restart_starts_nothing_when_written_again() -> None:
    with PlcLink(TcpEndpoint(LOCALHOST, 0)) as link:
        link.restore_last_cycle(41)
        link.set_status(cameras_ok=True, calibration_ok=True)
        with PlcSimulator(link.endpoint, response_timeout_s=1.0) as plc:
            assert plc.read_header().trigger == 41
            plc.trigger(41)  # a PLC writing its output block cyclically
            assert link.wait_trigger(timeout_s=0.3) is None
            plc.trigger(42)
            trigger = link.wait_trigger(timeout_s=2.0)
            assert trigger is not None and trigger.cycle == 42


# ---- bounded protocol fuzz ---------------------------------------------------------------------------


def fuzz_frames(seed: int, count: int) -> list[bytes]:
    """Random and hand-made malformed frames; none of them may write the trigger."""
    rng = random.Random(seed)
    hand_made = [
        b"",
        b"\x00",
        b"\x00\x01\x00\x00\x00\x06\x01",  # header without PDU
        mbap(b"") + b"x",
        struct.pack(">HHHB", 1, 0, 255, 1) + bytes(254),
        mbap(struct.pack(">BHHB", 16, Register.TRIGGER, 1, 4) + b"\x00\x09\x00\x09"),  # byte count lies
        mbap(struct.pack(">BHHB", 16, Register.TRIGGER, 2, 4) + b"\x00\x09\x00\x09"),  # covers 2 and 3
        mbap(struct.pack(">BHHHHBH", 23, MAP_SIZE - 1, 2, Register.TRIGGER, 1, 2, 9)),
        mbap(struct.pack(">BHHHHBH", 23, 0, 0, Register.TRIGGER, 1, 2, 9)),
        mbap(struct.pack(">BHH", 6, Register.TRIGGER, 9) + b"\x00"),  # one byte too many
        mbap(struct.pack(">BHH", 6, Register.STATUS, 9)),
        mbap(struct.pack(">BHH", 6, Register.TRIGGER, 9), unit=9),  # another unit id
    ]
    frames = list(hand_made)
    while len(frames) < count:
        kind = rng.randrange(3)
        if kind == 0:
            frames.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))))
        else:
            pdu = bytes([rng.choice([1, 2, 3, 4, 5, 8, 15, 17, 22, 24, 43, 90, 200])]) + bytes(
                rng.randrange(256) for _ in range(rng.randrange(0, 20))
            )
            frames.append(mbap(pdu, unit=rng.choice([1, 1, 0, 2, 255]), transaction=rng.randrange(65536)))
    return frames


def test_protocol_fuzz_changes_no_register_and_a_second_client_keeps_its_answers(link: PlcLink) -> None:
    with PlcSimulator(link.endpoint, response_timeout_s=1.0) as plc:
        before = plc.read_registers(1, 18)
        stop, polls, failures = threading.Event(), [0], []

        def poll() -> None:
            with PlcSimulator(link.endpoint, response_timeout_s=1.0) as watcher:
                while not stop.is_set():
                    try:
                        assert watcher.read_header().map_version == 1
                        polls[0] += 1
                    except Exception as exc:  # noqa: BLE001 - recorded and failed below
                        failures.append(exc)
                        return

        poller = threading.Thread(target=poll)
        poller.start()
        try:
            for payload in fuzz_frames(seed=15, count=300):
                with connect(link) as conn:
                    conn.settimeout(1.0)
                    conn.sendall(payload)
                    conn.shutdown(socket.SHUT_WR)
                    deadline = time.monotonic() + 2.0
                    while time.monotonic() < deadline:  # answers, then the server's close (or our EOF)
                        try:
                            if not conn.recv(512):
                                break
                        except (TimeoutError, ConnectionResetError):
                            break
        finally:
            stop.set()
            poller.join(5.0)
        assert not failures and polls[0] > 0
        assert plc.read_registers(1, 18) == before
        assert link.wait_trigger(timeout_s=0.05) is None


# ---- RTU: silence for other unit ids, exceptions only for our own ------------------------------------


def test_rtu_answers_only_its_unit_id_and_only_documented_function_codes(tmp_path: Path) -> None:
    cable = PtyNullModem(tmp_path)
    try:
        controller_side = SerialEndpoint(cable.controller_port, baudrate=115200, parity="N")
        with PlcLink(controller_side, unit_id=3), serial.Serial(cable.plc_port, 115200, timeout=0.3) as plc:

            def ask(unit: int, pdu: bytes) -> bytes:
                plc.reset_input_buffer()
                plc.write(rtu.frame(unit, pdu))
                return plc.read(64)

            for function in (8, 17, 43):
                assert ask(4, bytes([function, 0, 0])) == b""  # another slave's request: silence
                assert ask(3, bytes([function, 0, 0])) == rtu.frame(3, bytes([function | 0x80, 1]))
            assert ask(0, struct.pack(">BHH", 6, Register.TRIGGER, 5)) == b""  # broadcast: never answered
            assert ask(3, struct.pack(">BHH", 3, Register.MAP_VERSION, 1)) == rtu.frame(3, b"\x03\x02\x00\x01")
            bad_crc = bytearray(rtu.frame(3, struct.pack(">BHH", 3, Register.MAP_VERSION, 1)))
            bad_crc[-1] ^= 0xFF
            plc.write(bytes(bad_crc))
            assert plc.read(64) == b""
            assert ask(3, struct.pack(">BHH", 3, Register.MAP_VERSION, 1)) == rtu.frame(3, b"\x03\x02\x00\x01")
    finally:
        cable.close()


# ---- log hygiene ----------------------------------------------------------------------------------------


def test_wrong_unit_ids_and_foreign_function_codes_leave_no_log_lines(
    link: PlcLink, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level("DEBUG")
    with connect(link) as conn:
        for _ in range(50):
            conn.sendall(mbap(struct.pack(">BHH", 3, 0, 1), unit=7) + mbap(bytes([8, 0, 0, 0, 0])))
            assert read_reply(conn)[7:] == bytes([0x83, ExcCodes.GATEWAY_NO_RESPONSE])
            assert read_reply(conn)[7:] == bytes([0x88, ExcCodes.ILLEGAL_FUNCTION])
    assert [r for r in caplog.records if r.levelno >= 30] == []  # the PLC's mistakes are answers, not log lines


def test_a_flood_of_malformed_frames_logs_one_line(link: PlcLink, caplog: pytest.LogCaptureFixture) -> None:
    for _ in range(30):
        with connect(link) as conn:
            conn.sendall(b"\xff" * 7)
            assert closed_by_server(conn)
    assert len([r for r in caplog.records if r.levelno >= 30]) == 1
