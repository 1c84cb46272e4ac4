"""The result half of the register image: what the PLC reads about the last cycle, and the status register.

`firmware_io.handshake` decides when a result may be written (the handshake's state); this module decides
what the registers then hold: measurements, glue points, map v2's path registers, the error code and the
status bits, in the order that makes a result complete only once RESULT_CYCLE and the flags are written.
No lock here: the handshake holds its lock around every call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from numpy.typing import ArrayLike

from firmware_io.registers import (
    MAX_GLUE_POINTS,
    ErrorCode,
    FeatureBit,
    GlueFrame,
    MapLayout,
    Register,
    RegisterMap,
    StatusBit,
)

_NAN = math.nan
_MEASUREMENT_REGISTERS = Register.GLUE_POINT_COUNT - Register.HEEL_HEIGHT_MM  # 10..17: four float32


@dataclass(frozen=True)
class PathInfo:
    """What map version 2 publishes about the glue path besides its points."""

    normals: ArrayLike  #: N x 3 unit normals, one per glue point, in the same frame as the points
    frame: GlueFrame = GlueFrame.TABLE
    nozzle_offset_mm: float = 0.0  #: how far the points were moved along their normals
    glue_offset_mm: float = _NAN  #: inset of the path from the sole's edge


@dataclass(frozen=True)
class Inspection:
    """The result cycle's tolerance check (map v2); features in `failed` are outside their tolerance."""

    failed: FeatureBit = FeatureBit(0)


@dataclass(frozen=True)
class EncodedResult:
    """A cycle's answer as register values, encoded before the lock is taken (a refused value changes nothing)."""

    measurement: list[int]  # heel, toe, length, cycle time: four float32
    points: list[int]
    code: ErrorCode
    extra: dict[int, list[int]]  # map v2's registers besides the points
    inspection: Inspection | None = None


class ResultImage:
    """The register image (all of it, for the PLC's reads) with the writes of results and status."""

    def __init__(self, register_map: RegisterMap, layout: MapLayout) -> None:
        self._map = register_map
        self.layout = layout
        self.registers = [0] * layout.size
        self.registers[Register.MAP_VERSION] = layout.version
        self._flags = StatusBit(0)  # RESULT_VALID, ERROR, CAMERAS_OK, CALIBRATION_OK; the rest is derived
        self.clear()

    def encode_result(
        self,
        values: dict[str, float],
        glue_points: ArrayLike,
        path: PathInfo | None,
        inspection: Inspection | None,
    ) -> EncodedResult:
        """A measurement (heel, toe, length, cycle time) and its glue path; ValueError for values not finite."""
        for name, value in values.items():
            if not math.isfinite(float(value)):
                raise ValueError(f"{name} is {value}: publish_error(cycle, ErrorCode.MEASUREMENT_INVALID) instead")
        measurement = self._map.encode_floats(list(values.values()), what="measurement")
        if not self.layout.has_normals:
            return EncodedResult(measurement, self._map.encode_points(glue_points), ErrorCode.NONE, {}, inspection)
        if path is None:
            raise ValueError("register map version 2 publishes normals: pass path=PathInfo(normals, ...)")
        points = self._map.encode_path(glue_points, path.normals)
        return EncodedResult(measurement, points, ErrorCode.NONE, self._path_registers(path, inspection), inspection)

    def encode_error(self, code: ErrorCode, cycle_time_ms: float) -> EncodedResult:
        """An error answer: measurements read NaN, no glue points."""
        measurement = self._map.encode_floats([_NAN, _NAN, _NAN, cycle_time_ms], what="measurement")
        return EncodedResult(measurement, [], code, {})

    def write(self, cycle: int, result: EncodedResult, recipe: int) -> None:
        """The data registers first, then the cycle number and the flags that tell the PLC it is complete."""
        image = self.registers
        image[Register.HEEL_HEIGHT_MM : Register.GLUE_POINT_COUNT] = result.measurement
        image[Register.GLUE_POINT_COUNT] = len(result.points) // self.layout.registers_per_point
        image[Register.GLUE_POINTS : Register.GLUE_POINTS + len(result.points)] = result.points
        for address, registers in result.extra.items():
            image[address : address + len(registers)] = registers
        image[Register.ERROR_CODE] = result.code
        if self.layout.version >= 2:
            image[Register.RESULT_RECIPE] = recipe
        # Last: the cycle number and the flags that tell the PLC the result is complete.
        image[Register.RESULT_CYCLE] = cycle
        ok = result.code is ErrorCode.NONE
        self.set_flag(StatusBit.RESULT_VALID, ok)
        self.set_flag(StatusBit.ERROR, not ok)
        inspection = result.inspection if ok else None
        self.set_flag(StatusBit.IN_TOLERANCE, inspection is not None and not inspection.failed)
        self.set_flag(StatusBit.OUT_OF_TOLERANCE, inspection is not None and bool(inspection.failed))

    def clear(self) -> None:
        """No result: what the PLC reads from the moment a trigger is accepted until its answer."""
        image = self.registers
        image[Register.RESULT_CYCLE] = 0
        image[Register.ERROR_CODE] = ErrorCode.NONE
        self._flags &= ~(StatusBit.RESULT_VALID | StatusBit.ERROR | StatusBit.IN_TOLERANCE | StatusBit.OUT_OF_TOLERANCE)
        nan4 = self._map.encode_floats([_NAN] * 4)
        if len(nan4) != _MEASUREMENT_REGISTERS:
            raise RuntimeError(f"four float32 take {len(nan4)} registers, the map has {_MEASUREMENT_REGISTERS}")
        image[Register.HEEL_HEIGHT_MM : Register.GLUE_POINT_COUNT] = nan4
        image[Register.GLUE_POINT_COUNT] = 0
        image[Register.GLUE_POINTS :] = [0] * (self.layout.registers_per_point * MAX_GLUE_POINTS)
        if self.layout.version >= 2:
            image[Register.RESULT_RECIPE] = image[Register.FEATURE_FAILS] = image[Register.GLUE_FRAME] = 0
            image[Register.NOZZLE_OFFSET_MM : Register.GLUE_OFFSET_MM + 2] = self._map.encode_floats([_NAN] * 2)

    def set_flag(self, bit: StatusBit, on: bool) -> None:
        self._flags = (self._flags | bit) if on else (self._flags & ~bit)

    def update_status(self, busy: bool) -> None:
        """The status register from the flags: BUSY while a cycle runs, else READY when cameras and calibration are ok."""
        status = self._flags & self.layout.status_bits
        healthy = StatusBit.CAMERAS_OK | StatusBit.CALIBRATION_OK
        if busy:
            status |= StatusBit.BUSY
        elif status & healthy == healthy:
            status |= StatusBit.READY
        self.registers[Register.STATUS] = int(status)

    def _path_registers(self, path: PathInfo, inspection: Inspection | None) -> dict[int, list[int]]:
        """Map v2's registers besides the points: frame, nozzle and glue offsets (20-23), feature bits."""
        offsets = self._map.encode_floats([path.nozzle_offset_mm, path.glue_offset_mm], what="offset")
        return {
            Register.GLUE_FRAME: [int(GlueFrame(path.frame))],
            Register.NOZZLE_OFFSET_MM: offsets,
            Register.FEATURE_FAILS: [0 if inspection is None else int(inspection.failed)],
        }
