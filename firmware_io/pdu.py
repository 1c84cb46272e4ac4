"""Modbus request PDUs of this map: parsed and validated whole, then executed; no I/O here.

Why by hand and not pymodbus' request classes (the server used pymodbus 3.16 before): a PDU that
pymodbus decodes is executed piecewise; its read/write (fc 23) wrote the trigger before it found the
read range illegal, so a request answered with exception 0x02 had started a cycle. Its framer also
answered function codes this map does not serve (8, 17, 43, ...) and lost sync on one bad frame. The
map serves four function codes with fixed layouts, so a strict parser is ~100 lines: every field
is checked against the Modbus application protocol spec (V1.1b3, section 6) before anything is
written, and a request either runs whole or is answered with one exception and changes nothing.

    reply = execute(pdu, registers)      # registers: plc_read / plc_write, see RegisterAccess
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Sequence
from typing import Protocol


class ExceptionCode(enum.IntEnum):
    """Modbus exception codes this server answers with (same values as pymodbus' ExcCodes)."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_ADDRESS = 0x02
    ILLEGAL_VALUE = 0x03
    DEVICE_BUSY = 0x06
    GATEWAY_NO_RESPONSE = 0x0B


#: The only function codes served: read holding registers, write single, write multiple, read/write.
READ_HOLDING = 3
WRITE_SINGLE = 6
WRITE_MULTIPLE = 16
READ_WRITE = 23
SERVED_FUNCTIONS = frozenset({READ_HOLDING, WRITE_SINGLE, WRITE_MULTIPLE, READ_WRITE})

#: Quantity limits of the spec: 125 registers per read, 123 per write, 121 written by fc 23.
MAX_READ = 125
MAX_WRITE = 123
MAX_READ_WRITE_WRITE = 121


class RegisterAccess(Protocol):
    """What a request runs against (firmware_io.plc_side.PlcSide, a PlcHandshake): the served map's size and the
    registers a PLC may write depend on the map version."""

    @property
    def map_size(self) -> int: ...

    @property
    def plc_writable(self) -> frozenset[int]: ...

    def plc_read(self, address: int, count: int) -> list[int]: ...

    def plc_write(self, address: int, values: Sequence[int]) -> ExceptionCode | None: ...


class _Refused(Exception):
    def __init__(self, code: ExceptionCode) -> None:
        self.code = code


def exception_reply(function_code: int, code: ExceptionCode) -> bytes:
    """The exception PDU for a request's function code."""
    return bytes([(function_code | 0x80) & 0xFF, int(code)])


def execute(pdu: bytes, registers: RegisterAccess) -> bytes:
    """The reply PDU to a request PDU; a refused request changes nothing and gets one exception."""
    if not pdu:
        raise ValueError("empty PDU")
    function = pdu[0]
    try:
        if function == READ_HOLDING:
            address, count = _unpack(">HH", pdu)
            _check_read(registers, address, count)
            return _read_reply(function, registers.plc_read(address, count))
        if function == WRITE_SINGLE:
            address, value = _unpack(">HH", pdu)
            _check_write(registers, address, 1)
            _write(registers, address, [value])
            return pdu  # the echo the spec requires
        if function == WRITE_MULTIPLE:
            address, count, values = _write_multiple(pdu)
            _check_write(registers, address, count)
            _write(registers, address, values)
            return struct.pack(">BHH", function, address, count)
        if function == READ_WRITE:
            return _read_write(pdu, registers)
    except _Refused as refused:
        return exception_reply(function, refused.code)
    return exception_reply(function, ExceptionCode.ILLEGAL_FUNCTION)


def _read_write(pdu: bytes, registers: RegisterAccess) -> bytes:
    if len(pdu) < 10:
        raise _Refused(ExceptionCode.ILLEGAL_VALUE)
    read_address, read_count, write_address, write_count, byte_count = struct.unpack(">HHHHB", pdu[1:10])
    values = _values(pdu[10:], write_count, byte_count, MAX_READ_WRITE_WRITE)
    if not 1 <= read_count <= MAX_READ:
        raise _Refused(ExceptionCode.ILLEGAL_VALUE)
    # Both ranges are checked before the write: a refused read must not have started a cycle.
    _check_read(registers, read_address, read_count)
    _check_write(registers, write_address, write_count)
    _write(registers, write_address, values)  # the spec: the write is performed before the read
    return _read_reply(READ_WRITE, registers.plc_read(read_address, read_count))


def _write_multiple(pdu: bytes) -> tuple[int, int, list[int]]:
    if len(pdu) < 6:
        raise _Refused(ExceptionCode.ILLEGAL_VALUE)
    address, count, byte_count = struct.unpack(">HHB", pdu[1:6])
    return address, count, _values(pdu[6:], count, byte_count, MAX_WRITE)


def _values(data: bytes, count: int, byte_count: int, limit: int) -> list[int]:
    if not 1 <= count <= limit or byte_count != 2 * count or len(data) != byte_count:
        raise _Refused(ExceptionCode.ILLEGAL_VALUE)
    return list(struct.unpack(f">{count}H", data))


def _unpack(layout: str, pdu: bytes) -> tuple[int, int]:
    if len(pdu) != 1 + struct.calcsize(layout):
        raise _Refused(ExceptionCode.ILLEGAL_VALUE)
    first, second = struct.unpack(layout, pdu[1:])
    return first, second


def _check_read(registers: RegisterAccess, address: int, count: int) -> None:
    if not 1 <= count <= MAX_READ:
        raise _Refused(ExceptionCode.ILLEGAL_VALUE)
    if address + count > registers.map_size:
        raise _Refused(ExceptionCode.ILLEGAL_ADDRESS)


def _check_write(registers: RegisterAccess, address: int, count: int) -> None:
    if any(a not in registers.plc_writable for a in range(address, address + count)):
        raise _Refused(ExceptionCode.ILLEGAL_ADDRESS)


def _write(registers: RegisterAccess, address: int, values: list[int]) -> None:
    refused = registers.plc_write(address, values)
    if refused is not None:
        raise _Refused(refused)


def _read_reply(function: int, values: list[int]) -> bytes:
    return struct.pack(f">BB{len(values)}H", function, 2 * len(values), *values)
