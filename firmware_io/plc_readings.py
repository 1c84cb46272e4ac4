"""What the simulated PLC reads and how it fails: the header, one cycle's reading, the heartbeat watchdog,
and their text for `cellctl plc-sim` (docs/modbus.md). Kept beside each other so a change of the map is one
edit; the PLC program itself is firmware_io.plc_sim."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymodbus.constants import ExcCodes

from firmware_io.registers import ErrorCode, FeatureBit, GlueFrame, Register, RegisterMap, StatusBit


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


def status_text(status: StatusBit) -> str:
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
        f"status={status_text(reading.status)} latency={reading.latency_s * 1000:.1f} ms"
    )


def decode_header(regs: list[int], register_map: RegisterMap, version: int) -> PlcHeader:
    """The header registers (0..18, or 0..23 in map v2) as the PLC reads them."""
    heel, toe, length, cycle_time = register_map.decode_floats(
        regs[Register.HEEL_HEIGHT_MM : Register.GLUE_POINT_COUNT]
    )
    extra: dict[str, Any] = {}
    if version >= 2:
        nozzle, glue = register_map.decode_floats(regs[Register.NOZZLE_OFFSET_MM : Register.GLUE_OFFSET_MM + 2])
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


def reading_of(
    cycle: int, header: PlcHeader, points: np.ndarray, normals: np.ndarray, version: int, latency_s: float
) -> CycleReading:
    """A finished cycle's reading: its header and glue path."""
    return CycleReading(
        map_version=version,
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
