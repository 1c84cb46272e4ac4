"""Register map encoding and the handshake state machine, without any sockets."""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import numpy as np
import pytest
from pymodbus.constants import ExcCodes

from firmware_io.endpoints import SerialEndpoint, TcpEndpoint, check_unit_id
from firmware_io.handshake import PlcHandshake
from firmware_io.registers import (
    MAP_SIZE,
    MAX_GLUE_POINTS,
    PLC_WRITABLE,
    ErrorCode,
    Register,
    RegisterMap,
    StatusBit,
    WordOrder,
)

DOCS = Path(__file__).resolve().parents[2] / "docs" / "modbus.md"
HIGH = RegisterMap(WordOrder.HIGH_FIRST)
LOW = RegisterMap(WordOrder.LOW_FIRST)


# ---- float32 encoding ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "high_word", "low_word"),
    [(1.0, 0x3F80, 0x0000), (-2.5, 0xC020, 0x0000), (123.456, 0x42F6, 0xE979), (0.0, 0x0000, 0x0000)],
)
def test_float32_words_follow_the_configured_order(value: float, high_word: int, low_word: int) -> None:
    assert HIGH.encode_floats([value]) == [high_word, low_word]
    assert LOW.encode_floats([value]) == [low_word, high_word]
    assert HIGH.decode_floats([high_word, low_word]) == [pytest.approx(value, rel=1e-7)]
    assert LOW.decode_floats([low_word, high_word]) == [pytest.approx(value, rel=1e-7)]


def test_float32_decoding_with_the_wrong_order_gives_a_different_value() -> None:
    registers = HIGH.encode_floats([123.456])
    assert LOW.decode_floats(registers)[0] != pytest.approx(123.456, rel=1e-3)


def test_float32_refuses_values_too_large_and_odd_register_counts() -> None:
    with pytest.raises(ValueError, match="too large for a float32"):
        HIGH.encode_floats([1e39])
    with pytest.raises(ValueError, match="2 registers each"):
        HIGH.decode_floats([1, 2, 3])


@pytest.mark.parametrize("register_map", [HIGH, LOW])
def test_glue_points_round_trip_at_full_size(register_map: RegisterMap) -> None:
    points = np.random.default_rng(6).uniform(-400, 400, size=(MAX_GLUE_POINTS, 3))
    registers = register_map.encode_points(points)
    assert len(registers) == 6 * MAX_GLUE_POINTS
    assert Register.GLUE_POINTS + len(registers) == MAP_SIZE
    np.testing.assert_array_equal(register_map.decode_points(registers), points.astype(np.float32))


def test_glue_points_refuse_wrong_shapes_and_too_many_points() -> None:
    with pytest.raises(ValueError, match="at most 2000"):
        HIGH.encode_points(np.zeros((MAX_GLUE_POINTS + 1, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        HIGH.encode_points(np.zeros((4, 2)))
    assert HIGH.encode_points(np.zeros((0, 3))) == []


# ---- map constants, error codes and their documentation ------------------------------------------


def test_only_the_trigger_is_plc_writable_and_fields_do_not_overlap() -> None:
    assert PLC_WRITABLE == {Register.TRIGGER}
    floats = [Register.HEEL_HEIGHT_MM, Register.TOE_HEIGHT_MM, Register.LENGTH_MM, Register.CYCLE_TIME_MS]
    assert [b - a for a, b in zip(floats, floats[1:])] == [2, 2, 2]
    assert Register.CYCLE_TIME_MS + 2 == Register.GLUE_POINT_COUNT
    assert MAP_SIZE == 100 + 6 * MAX_GLUE_POINTS


def test_every_error_code_has_a_meaning_an_action_and_a_row_in_the_docs() -> None:
    docs = DOCS.read_text(encoding="utf-8")
    assert len({int(c) for c in ErrorCode}) == len(ErrorCode)
    for code in ErrorCode:
        assert code.meaning and code.operator_action
        row = re.search(rf"^\|\s*{int(code)}\s*\|\s*`{code.name}`\s*\|", docs, re.MULTILINE)
        assert row, f"docs/modbus.md has no table row for error code {int(code)} {code.name}"


def test_every_register_and_status_bit_is_documented() -> None:
    docs = DOCS.read_text(encoding="utf-8")
    for register in Register:
        assert re.search(rf"^\|\s*{int(register)}\b", docs, re.MULTILINE), f"register {register.name} undocumented"
    for bit in StatusBit:
        position = int(bit).bit_length() - 1
        assert re.search(rf"^\|\s*{position}\s*\|\s*`{bit.name}`", docs, re.MULTILINE), f"bit {bit.name} undocumented"


def test_unit_ids_are_checked_per_transport() -> None:
    assert check_unit_id(0, TcpEndpoint()) == 0
    with pytest.raises(ValueError, match="0 is broadcast"):
        check_unit_id(0, SerialEndpoint("/dev/ttyUSB0"))
    with pytest.raises(ValueError, match="0..255"):
        check_unit_id(256, TcpEndpoint())
    with pytest.raises(ValueError, match="parity"):
        SerialEndpoint("/dev/ttyUSB0", parity="X")  # type: ignore[arg-type]


# ---- handshake state machine ---------------------------------------------------------------------


def healthy_handshake() -> PlcHandshake:
    handshake = PlcHandshake(HIGH)
    handshake.set_health(cameras_ok=True, calibration_ok=True)
    return handshake


def registers(handshake: PlcHandshake, register: Register, count: int = 1) -> list[int]:
    return handshake.plc_read(register, count)


def publish(handshake: PlcHandshake, cycle: int, points: int = 3) -> None:
    handshake.publish_result(
        cycle,
        heel_height_mm=12.5,
        toe_height_mm=8.25,
        length_mm=271.0,
        cycle_time_ms=420.0,
        glue_points=np.arange(points * 3, dtype=float).reshape(points, 3),
    )


def test_ready_needs_cameras_and_calibration() -> None:
    handshake = PlcHandshake(HIGH)
    assert handshake.status == StatusBit(0)
    handshake.set_health(cameras_ok=True, calibration_ok=False)
    assert handshake.status == StatusBit.CAMERAS_OK
    handshake.set_health(cameras_ok=True, calibration_ok=True)
    assert handshake.status == StatusBit.CAMERAS_OK | StatusBit.CALIBRATION_OK | StatusBit.READY


def test_trigger_clears_the_previous_result_before_it_is_acknowledged() -> None:
    handshake = healthy_handshake()
    assert handshake.plc_write(Register.TRIGGER, [7]) is None
    publish(handshake, handshake.wait_trigger(0, 0.1).cycle)  # type: ignore[union-attr]
    assert registers(handshake, Register.RESULT_CYCLE) == [7]
    assert handshake.status & StatusBit.RESULT_VALID

    assert handshake.plc_write(Register.TRIGGER, [8]) is None
    status = handshake.status
    assert status & StatusBit.BUSY and not status & (StatusBit.READY | StatusBit.RESULT_VALID | StatusBit.ERROR)
    assert registers(handshake, Register.RESULT_CYCLE) == [0]
    assert registers(handshake, Register.GLUE_POINT_COUNT) == [0]
    assert all(math.isnan(v) for v in HIGH.decode_floats(registers(handshake, Register.HEEL_HEIGHT_MM, 8)))
    assert registers(handshake, Register.GLUE_POINTS, 18) == [0] * 18


def test_zero_and_repeated_numbers_start_nothing() -> None:
    handshake = healthy_handshake()
    assert handshake.plc_write(Register.TRIGGER, [0]) is None
    assert handshake.wait_trigger(0, 0.1) is None
    handshake.plc_write(Register.TRIGGER, [5])
    assert handshake.wait_trigger(0, 0.1).cycle == 5  # type: ignore[union-attr]
    assert handshake.plc_write(Register.TRIGGER, [5]) is None  # retried write while running
    publish(handshake, 5)
    assert handshake.plc_write(Register.TRIGGER, [5]) is None  # repeated write after completion
    assert handshake.wait_trigger(0, 0.1) is None
    assert handshake.status & StatusBit.RESULT_VALID


def test_a_different_trigger_while_busy_is_refused_and_counted() -> None:
    handshake = healthy_handshake()
    handshake.plc_write(Register.TRIGGER, [10])
    assert handshake.plc_write(Register.TRIGGER, [11]) == ExcCodes.DEVICE_BUSY
    assert handshake.plc_write(Register.TRIGGER, [12]) == ExcCodes.DEVICE_BUSY
    assert registers(handshake, Register.REFUSED_TRIGGERS) == [2]
    assert registers(handshake, Register.TRIGGER) == [10]
    assert handshake.wait_trigger(0, 0.1).cycle == 10  # type: ignore[union-attr]
    assert handshake.wait_trigger(0, 0.1) is None


def test_writes_other_than_the_trigger_never_reach_the_handshake() -> None:
    # The server refuses them with 0x02 first; reaching here would be a wiring bug (answered 0x04).
    with pytest.raises(ValueError, match="only the trigger register is writable"):
        healthy_handshake().plc_write(Register.RESULT_CYCLE, [1])
    with pytest.raises(ValueError, match="only the trigger register is writable"):
        healthy_handshake().plc_write(Register.TRIGGER, [1, 2])


def test_publish_refuses_the_wrong_cycle_and_non_finite_values_without_touching_the_map() -> None:
    handshake = healthy_handshake()
    with pytest.raises(RuntimeError, match="running cycle is None"):
        publish(handshake, 1)
    handshake.plc_write(Register.TRIGGER, [3])
    with pytest.raises(RuntimeError, match="cannot publish cycle 4"):
        publish(handshake, 4)
    before = registers(handshake, Register.HEARTBEAT, 40)
    with pytest.raises(ValueError, match="heel_height_mm is nan"):
        handshake.publish_result(
            3, heel_height_mm=math.nan, toe_height_mm=1, length_mm=1, cycle_time_ms=1, glue_points=[]
        )
    with pytest.raises(ValueError, match="at most 2000"):
        publish(handshake, 3, points=MAX_GLUE_POINTS + 1)
    assert registers(handshake, Register.HEARTBEAT, 40) == before
    assert handshake.status & StatusBit.BUSY
    handshake.publish_error(3, ErrorCode.INTERNAL_ERROR, cycle_time_ms=5.0)
    assert registers(handshake, Register.ERROR_CODE) == [ErrorCode.INTERNAL_ERROR]


def test_error_result_sets_error_bit_nan_measurements_and_no_points() -> None:
    handshake = healthy_handshake()
    handshake.plc_write(Register.TRIGGER, [1])
    publish(handshake, 1, points=50)
    handshake.plc_write(Register.TRIGGER, [2])
    handshake.publish_error(2, ErrorCode.SOLE_AT_BORDER, cycle_time_ms=88.5)
    assert handshake.status & StatusBit.ERROR and not handshake.status & StatusBit.RESULT_VALID
    assert registers(handshake, Register.RESULT_CYCLE, 2) == [2, ErrorCode.SOLE_AT_BORDER]
    heel, toe, length, cycle_time = HIGH.decode_floats(registers(handshake, Register.HEEL_HEIGHT_MM, 8))
    assert math.isnan(heel) and math.isnan(toe) and math.isnan(length) and cycle_time == 88.5
    assert registers(handshake, Register.GLUE_POINT_COUNT) == [0]
    assert registers(handshake, Register.GLUE_POINTS, 300) == [0] * 300  # the previous cycle's 50 points are gone
    with pytest.raises(ValueError, match="other than ErrorCode.NONE"):
        handshake.plc_write(Register.TRIGGER, [3])
        handshake.publish_error(3, ErrorCode.NONE, cycle_time_ms=1.0)


def test_heartbeat_stops_when_the_controller_goes_silent() -> None:
    handshake = healthy_handshake()
    assert handshake.beat(liveness_timeout_s=10.0)
    assert registers(handshake, Register.HEARTBEAT) == [1]
    time.sleep(0.05)
    assert not handshake.beat(liveness_timeout_s=0.01)
    assert registers(handshake, Register.HEARTBEAT) == [1]
    handshake.set_health(cameras_ok=True, calibration_ok=True)  # any controller call revives it
    assert handshake.beat(liveness_timeout_s=0.01)
    assert registers(handshake, Register.HEARTBEAT) == [2]


def test_heartbeat_wraps_around() -> None:
    handshake = healthy_handshake()
    for _ in range(0x10000):
        handshake.beat(liveness_timeout_s=None)
    assert registers(handshake, Register.HEARTBEAT) == [0]
