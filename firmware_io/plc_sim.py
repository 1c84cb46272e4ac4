"""A PLC simulator: triggers cycles and reads results over Modbus exactly as the robot PLC does.

Used by `cellctl plc-sim`, by `make demo` and as a test fixture. It speaks only the documented
protocol (docs/modbus.md), through pymodbus' synchronous client, because a PLC program is a
sequential poll loop too:

    [write RECIPE_SELECT = r]  ->  write TRIGGER = N  ->  poll the header until RESULT_CYCLE == N  ->  read glue points

It speaks the map version the controller announces in register 6 (or insists on one, as a programmed PLC
does): version 1 reads 0..18 and x, y, z per point, version 2 reads 0..23 and x, y, z, nx, ny, nz.

and on every poll it feeds a heartbeat watchdog that fails when register 0 stops changing.

What it reads (header, reading, their text) is firmware_io.plc_readings; its raw register access is
firmware_io.modbus_master.
"""

from __future__ import annotations

import time

import numpy as np
from pymodbus.constants import ExcCodes

from firmware_io.endpoints import Endpoint, TcpEndpoint
from firmware_io.modbus_master import ModbusMaster
from firmware_io.plc_readings import (
    CycleReading,
    HeartbeatLost,
    HeartbeatWatchdog,
    ModbusRequestError,
    PlcHeader,
    PlcSimError,
    ResultTimeout,
    TriggerRefused,
    decode_header,
    describe,
    reading_of,
    status_text,
)
from firmware_io.registers import (
    MapLayout,
    Register,
    RegisterMap,
    StatusBit,
    WordOrder,
)

__all__ = [
    "CycleReading",
    "HeartbeatLost",
    "ModbusRequestError",
    "PlcSimError",
    "PlcSimulator",
    "ResultTimeout",
    "TriggerRefused",
    "describe",
]

#: Registers per read request for the glue points: 120, under Modbus' 125-register limit (20 points of
#: version 1, 10 of version 2).
REGISTERS_PER_READ = 120


class PlcSimulator(ModbusMaster):
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
        super().__init__(endpoint, unit_id, response_timeout_s)
        self._map = RegisterMap(word_order)
        self._poll_interval_s = poll_interval_s
        self.watchdog = HeartbeatWatchdog(heartbeat_limit_s)
        self._last_cycle = 0

    # ---- connection ----------------------------------------------------------------------------

    def connect(self) -> None:
        """Connect, check the map version and continue cycle numbering after the controller's last one."""
        self._connect_client()
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
        return decode_header(regs, self._map, self.layout.version)

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
                    f"status {status_text(header.status)})"
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

    # ---- internals -----------------------------------------------------------------------------

    def _reading(self, cycle: int, header: PlcHeader, latency_s: float) -> CycleReading:
        registers = self._read_point_registers(header.glue_point_count)
        if self.layout.has_normals:
            points, normals = self._map.decode_path(registers)
        else:
            points, normals = self._map.decode_points(registers), np.zeros((0, 3), np.float32)
        return reading_of(cycle, header, points, normals, self.layout.version, latency_s)

    def _read_point_registers(self, count: int) -> list[int]:
        per_point = self.layout.registers_per_point
        per_read = REGISTERS_PER_READ // per_point
        registers: list[int] = []
        for first in range(0, count, per_read):
            n = min(per_read, count - first)
            registers += self.read_registers(Register.GLUE_POINTS + first * per_point, n * per_point)
        return registers
