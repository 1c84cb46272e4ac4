"""A PLC simulator: triggers cycles and reads results over Modbus exactly as the robot PLC does.

Used by `cellctl plc-sim`, by `make demo` and as a test fixture. It speaks only the documented
protocol (docs/modbus.md), through pymodbus' synchronous client, because a PLC program is a
sequential poll loop too:

    [write RECIPE_SELECT = r]  ->  write TRIGGER = N  ->  poll the header until RESULT_CYCLE == N  ->  read glue points

It speaks the map version the controller announces in register 6 (or insists on one, as a programmed PLC
does): version 1 reads 0..18 and x, y, z per point, version 2 reads 0..23 and x, y, z, nx, ny, nz.

and on every poll it feeds a heartbeat watchdog that fails when register 0 stops changing.

Longer than most modules (~460 lines): it is one PLC program, and what it reads (header, reading, their
text for `cellctl plc-sim`) is kept beside the reading so a change of the map is one edit here.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType

from firmware_io.endpoints import Endpoint, SerialEndpoint, TcpEndpoint, check_unit_id
from firmware_io.registers import (
    ErrorCode,
    FeatureBit,
    GlueFrame,
    MapLayout,
    Register,
    RegisterMap,
    StatusBit,
    WordOrder,
)

#: Registers per read request for the glue points: 120, under Modbus' 125-register limit (20 points of
#: version 1, 10 of version 2).
REGISTERS_PER_READ = 120


class PlcSimError(Exception):
    """The controller did not behave as the handshake promises (or could not be reached)."""


class HeartbeatLost(PlcSimError):
    """The heartbeat register did not change within the watchdog limit."""


class ResultTimeout(PlcSimError):
    """RESULT_CYCLE did not reach the triggered cycle in time."""


class TriggerRefused(PlcSimError):
    """The controller answered the trigger write with exception 0x06 (a cycle is running)."""


class ModbusRequestError(PlcSimError):
    """A request was answered with a Modbus exception."""

    def __init__(self, what: str, exception_code: int) -> None:
        try:
            name = ExcCodes(exception_code).name
        except ValueError:
            name = "unknown"
        super().__init__(f"{what}: Modbus exception 0x{exception_code:02X} {name}")
        self.exception_code = exception_code


class HeartbeatWatchdog:
    """Fails when the heartbeat value stays the same for longer than limit_s."""

    def __init__(self, limit_s: float = 1.5) -> None:
        if limit_s <= 0:
            raise ValueError(f"heartbeat watchdog limit {limit_s} s must be positive")
        self.limit_s = limit_s
        self._value: int | None = None
        self._changed_at = 0.0

    def observe(self, value: int, now: float | None = None) -> None:
        """Record a heartbeat reading; raises HeartbeatLost if it has been stuck too long."""
        now = time.monotonic() if now is None else now
        if value != self._value:
            self._value, self._changed_at = value, now
        elif now - self._changed_at > self.limit_s:
            raise HeartbeatLost(
                f"heartbeat stuck at {value} for {now - self._changed_at:.2f} s (limit {self.limit_s} s): "
                "the controller is hung or stopped"
            )


@dataclass(frozen=True)
class PlcHeader:
    """Registers 0..18, read in one request as a PLC does."""

    heartbeat: int
    status: StatusBit
    trigger: int
    result_cycle: int
    error_code: int
    refused_triggers: int
    map_version: int
    heel_height_mm: float
    toe_height_mm: float
    length_mm: float
    cycle_time_ms: float
    glue_point_count: int
    # Map version 2 (0 or NaN in version 1):
    recipe_select: int = 0
    result_recipe: int = 0
    feature_fails: int = 0
    glue_frame: int = 0
    nozzle_offset_mm: float = math.nan
    glue_offset_mm: float = math.nan


@dataclass(frozen=True)
class CycleReading:
    """What the PLC received for one cycle."""

    cycle: int
    status: StatusBit
    error_code: int
    heel_height_mm: float
    toe_height_mm: float
    length_mm: float
    cycle_time_ms: float
    glue_points: np.ndarray = field(repr=False)
    latency_s: float  #: from the trigger write to the PLC seeing RESULT_CYCLE == cycle
    map_version: int = 1
    glue_normals: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3), np.float32))
    recipe: int = 0
    feature_fails: FeatureBit = FeatureBit(0)
    glue_frame: int = GlueFrame.TABLE
    nozzle_offset_mm: float = math.nan
    glue_offset_mm: float = math.nan

    @property
    def ok(self) -> bool:
        """True if the cycle delivered a valid measurement."""
        return bool(self.status & StatusBit.RESULT_VALID) and self.error_code == ErrorCode.NONE

    @property
    def in_tolerance(self) -> bool | None:
        """Map v2: True/False from the tolerance bits, None when no tolerances were checked."""
        if self.status & StatusBit.OUT_OF_TOLERANCE:
            return False
        return True if self.status & StatusBit.IN_TOLERANCE else None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly view (NaN becomes None)."""

        def number(value: float) -> float | None:
            return None if np.isnan(value) else round(float(value), 4)

        return {
            "cycle": self.cycle,
            "ok": self.ok,
            "status": int(self.status),
            "error_code": self.error_code,
            "error": _error_name(self.error_code),
            "heel_height_mm": number(self.heel_height_mm),
            "toe_height_mm": number(self.toe_height_mm),
            "length_mm": number(self.length_mm),
            "cycle_time_ms": number(self.cycle_time_ms),
            "glue_point_count": len(self.glue_points),
            "glue_points": np.round(self.glue_points.astype(float), 4).tolist(),
            "latency_s": round(self.latency_s, 4),
            "map_version": self.map_version,
            "glue_normals": np.round(self.glue_normals.astype(float), 5).tolist(),
            "recipe": self.recipe,
            "in_tolerance": self.in_tolerance,
            "feature_fails": [bit.name for bit in FeatureBit if self.feature_fails & bit],
            "glue_frame": _frame_name(self.glue_frame),
            "nozzle_offset_mm": number(self.nozzle_offset_mm),
            "glue_offset_mm": number(self.glue_offset_mm),
        }


class PlcSimulator:
    """Drives the controller's Modbus map the way the robot PLC does."""

    def __init__(
        self,
        endpoint: Endpoint = TcpEndpoint(),
        *,
        unit_id: int = 1,
        word_order: WordOrder = WordOrder.HIGH_FIRST,
        response_timeout_s: float = 1.0,
        heartbeat_limit_s: float = 1.5,
        poll_interval_s: float = 0.01,
        map_version: int | None = None,
    ) -> None:
        """map_version: the version this "PLC" is programmed for (refuses another); None takes the controller's."""
        self._expected_version = None if map_version is None else MapLayout.of(map_version).version
        self.layout = MapLayout.of(1)
        self._endpoint = endpoint
        self._unit_id = check_unit_id(unit_id, endpoint)
        self._map = RegisterMap(word_order)
        self._poll_interval_s = poll_interval_s
        self.watchdog = HeartbeatWatchdog(heartbeat_limit_s)
        self._client = _make_client(endpoint, response_timeout_s)
        self._last_cycle = 0

    # ---- connection ----------------------------------------------------------------------------

    def connect(self) -> None:
        """Connect, check the map version and continue cycle numbering after the controller's last one."""
        if not self._client.connect():
            raise PlcSimError(f"cannot connect to the controller at {self._endpoint} (is `cellctl run` running?)")
        version = self.read_registers(Register.MAP_VERSION, 1)[0]
        if self._expected_version is not None and version != self._expected_version:
            raise PlcSimError(
                f"controller serves register map version {version}, this PLC is programmed for "
                f"{self._expected_version}: set [plc] map_version in the controller's config"
            )
        try:
            self.layout = MapLayout.of(version)
        except ValueError as exc:
            raise PlcSimError(f"controller: {exc}") from None
        header = self.read_header()
        self._last_cycle = max(header.trigger, header.result_cycle)

    def close(self) -> None:
        """Drop the connection (the controller must carry on as if the PLC went away)."""
        self._client.close()

    def __enter__(self) -> PlcSimulator:
        self.connect()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ---- PLC operations ------------------------------------------------------------------------

    def read_header(self) -> PlcHeader:
        """Read the header (0..18, or 0..23 in map v2) in one request and feed the heartbeat watchdog."""
        regs = self.read_registers(0, self.layout.header_size)
        self.watchdog.observe(regs[Register.HEARTBEAT])
        heel, toe, length, cycle_time = self._map.decode_floats(
            regs[Register.HEEL_HEIGHT_MM : Register.GLUE_POINT_COUNT]
        )
        extra: dict[str, Any] = {}
        if self.layout.version >= 2:
            nozzle, glue = self._map.decode_floats(regs[Register.NOZZLE_OFFSET_MM : Register.GLUE_OFFSET_MM + 2])
            extra = dict(
                recipe_select=regs[Register.RECIPE_SELECT],
                result_recipe=regs[Register.RESULT_RECIPE],
                feature_fails=regs[Register.FEATURE_FAILS],
                glue_frame=regs[Register.GLUE_FRAME],
                nozzle_offset_mm=nozzle,
                glue_offset_mm=glue,
            )
        return PlcHeader(
            **extra,
            heartbeat=regs[Register.HEARTBEAT],
            status=StatusBit(regs[Register.STATUS]),
            trigger=regs[Register.TRIGGER],
            result_cycle=regs[Register.RESULT_CYCLE],
            error_code=regs[Register.ERROR_CODE],
            refused_triggers=regs[Register.REFUSED_TRIGGERS],
            map_version=regs[Register.MAP_VERSION],
            heel_height_mm=heel,
            toe_height_mm=toe,
            length_mm=length,
            cycle_time_ms=cycle_time,
            glue_point_count=regs[Register.GLUE_POINT_COUNT],
        )

    def next_cycle_number(self) -> int:
        """The cycle number after the last one used: 1..65535, skipping 0 on wrap-around."""
        return self._last_cycle % 0xFFFF + 1

    def trigger(self, cycle: int) -> None:
        """Write the trigger register; TriggerRefused if the controller is busy with another cycle."""
        if not 1 <= cycle <= 0xFFFF:
            raise ValueError(f"cycle number {cycle} must be 1..65535")
        try:
            self.write_register(Register.TRIGGER, cycle)
        except ModbusRequestError as exc:
            if exc.exception_code == ExcCodes.DEVICE_BUSY:
                raise TriggerRefused(f"trigger {cycle} refused: the controller is busy with another cycle") from exc
            raise
        self._last_cycle = cycle

    def wait_result(self, cycle: int, timeout_s: float = 5.0, *, started_at: float | None = None) -> CycleReading:
        """Poll until RESULT_CYCLE == cycle, then read the glue points; returns what the PLC got."""
        started_at = time.monotonic() if started_at is None else started_at
        deadline = time.monotonic() + timeout_s
        while True:
            header = self.read_header()
            if header.result_cycle == cycle and not header.status & StatusBit.BUSY:
                latency = time.monotonic() - started_at
                return self._reading(cycle, header, latency)
            if time.monotonic() > deadline:
                raise ResultTimeout(
                    f"no result for cycle {cycle} within {timeout_s} s (result cycle {header.result_cycle}, "
                    f"status {_status_text(header.status)})"
                )
            time.sleep(self._poll_interval_s)

    def select_recipe(self, recipe: int) -> None:
        """Write RECIPE_SELECT (map v2): the recipe the next trigger measures with."""
        if self.layout.version < 2:
            raise PlcSimError("recipes need register map version 2; the controller serves version 1")
        if not 0 <= recipe <= 0xFFFF:
            raise ValueError(f"recipe number {recipe} must be 0..65535")
        self.write_register(Register.RECIPE_SELECT, recipe)

    def run_cycle(self, cycle: int | None = None, timeout_s: float = 5.0, *, recipe: int | None = None) -> CycleReading:
        """Trigger one cycle (the next number by default), after selecting `recipe` if given; wait for its result."""
        cycle = self.next_cycle_number() if cycle is None else cycle
        if recipe is not None:
            self.select_recipe(recipe)
        started_at = time.monotonic()
        self.trigger(cycle)
        return self.wait_result(cycle, timeout_s, started_at=started_at)

    def watch_heartbeat(self, duration_s: float) -> None:
        """Keep polling the header for duration_s (a PLC idling between cycles); HeartbeatLost on a stall."""
        end = time.monotonic() + duration_s
        while True:
            self.read_header()
            if time.monotonic() >= end:
                return
            time.sleep(min(0.1, max(0.0, end - time.monotonic())))

    # ---- raw register access (also used by tests for malformed requests) ------------------------

    def read_registers(self, address: int, count: int) -> list[int]:
        """Function code 3; ModbusRequestError on an exception response."""
        response = self._execute(self._client.read_holding_registers, address, count=count)
        if response.isError():
            raise ModbusRequestError(f"reading {count} registers at {address}", response.exception_code)
        return list(response.registers)

    def write_register(self, address: int, value: int) -> None:
        """Function code 6; ModbusRequestError on an exception response."""
        response = self._execute(self._client.write_register, address, value)
        if response.isError():
            raise ModbusRequestError(f"writing {value} to register {address}", response.exception_code)

    def write_registers(self, address: int, values: list[int]) -> None:
        """Function code 16; ModbusRequestError on an exception response."""
        response = self._execute(self._client.write_registers, address, values)
        if response.isError():
            raise ModbusRequestError(f"writing {len(values)} registers at {address}", response.exception_code)

    # ---- internals -----------------------------------------------------------------------------

    def _execute(self, request: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return request(*args, device_id=self._unit_id, **kwargs)
        except ModbusException as exc:  # connection refused or lost, no answer within the timeout
            raise PlcSimError(f"no answer from the controller at {self._endpoint}: {exc}") from exc

    def _reading(self, cycle: int, header: PlcHeader, latency_s: float) -> CycleReading:
        registers = self._read_point_registers(header.glue_point_count)
        if self.layout.has_normals:
            points, normals = self._map.decode_path(registers)
        else:
            points, normals = self._map.decode_points(registers), np.zeros((0, 3), np.float32)
        return CycleReading(
            map_version=self.layout.version,
            glue_normals=normals,
            recipe=header.result_recipe,
            feature_fails=FeatureBit(header.feature_fails),
            glue_frame=header.glue_frame,
            nozzle_offset_mm=header.nozzle_offset_mm,
            glue_offset_mm=header.glue_offset_mm,
            cycle=cycle,
            status=header.status,
            error_code=header.error_code,
            heel_height_mm=header.heel_height_mm,
            toe_height_mm=header.toe_height_mm,
            length_mm=header.length_mm,
            cycle_time_ms=header.cycle_time_ms,
            glue_points=points,
            latency_s=latency_s,
        )

    def _read_point_registers(self, count: int) -> list[int]:
        per_point = self.layout.registers_per_point
        per_read = REGISTERS_PER_READ // per_point
        registers: list[int] = []
        for first in range(0, count, per_read):
            n = min(per_read, count - first)
            registers += self.read_registers(Register.GLUE_POINTS + first * per_point, n * per_point)
        return registers


def _make_client(endpoint: Endpoint, timeout_s: float) -> ModbusTcpClient | ModbusSerialClient:
    # retries=0: a PLC that gets no answer reports it; silent retries would hide a slow controller.
    if isinstance(endpoint, SerialEndpoint):
        return ModbusSerialClient(
            endpoint.port,
            framer=FramerType.RTU,
            baudrate=endpoint.baudrate,
            parity=endpoint.parity,
            stopbits=endpoint.stopbits,
            bytesize=endpoint.bytesize,
            timeout=timeout_s,
            retries=0,
        )
    return ModbusTcpClient(endpoint.host, port=endpoint.port, timeout=timeout_s, retries=0)


def _known_error(code: int) -> ErrorCode | None:
    try:
        return ErrorCode(code)
    except ValueError:
        return None


def _error_name(code: int) -> str:
    known = _known_error(code)
    return known.name if known is not None else f"UNKNOWN_{code}"


def _frame_name(frame: int) -> str:
    try:
        return GlueFrame(frame).name.lower()
    except ValueError:
        return f"unknown_{frame}"


def _status_text(status: StatusBit) -> str:
    names = [bit.name for bit in StatusBit if status & bit and bit.name]
    return "|".join(names) or "0"


def describe(reading: CycleReading) -> str:
    """One human line per cycle, as `cellctl plc-sim` prints it."""
    if reading.ok:
        line = (
            f"cycle {reading.cycle}: ok heel={reading.heel_height_mm:.2f} mm toe={reading.toe_height_mm:.2f} mm "
            f"length={reading.length_mm:.2f} mm points={len(reading.glue_points)} "
            f"cycle_time={reading.cycle_time_ms:.1f} ms latency={reading.latency_s * 1000:.1f} ms"
        )
        if reading.map_version >= 2:
            verdict = {True: "pass", False: "FAIL", None: "not checked"}[reading.in_tolerance]
            fails = "|".join(bit.name or "" for bit in FeatureBit if reading.feature_fails & bit)
            line += (
                f" recipe={reading.recipe} tolerance={verdict}{' ' + fails if fails else ''} "
                f"frame={_frame_name(reading.glue_frame)} normals={len(reading.glue_normals)}"
            )
        return line
    code = reading.error_code
    known = _known_error(code)
    meaning = known.meaning if known is not None else "unknown error code"
    return (
        f"cycle {reading.cycle}: error {code} {_error_name(code)} ({meaning}) "
        f"status={_status_text(reading.status)} latency={reading.latency_s * 1000:.1f} ms"
    )
