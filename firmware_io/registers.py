"""The holding-register map the robot PLC reads, and how values are encoded in it.

Everything the PLC sees is a holding register (function codes 3, 6, 16, 23), 0-based addresses:

    0        heartbeat            uint16, +1 at least every 500 ms while the controller is alive (wraps)
    1        status               uint16 bit field, see StatusBit
    2        trigger              uint16, the ONLY PLC-writable register: a new non-zero cycle number
    3        result cycle         uint16, cycle whose result (or error) registers 4..N hold
    4        error code           uint16, ErrorCode of the result cycle (0 = none)
    5        refused triggers     uint16, triggers refused because a cycle was running (wraps)  [extension]
    6        map version          uint16, MAP_VERSION                                           [extension]
    10-11    heel_height_mm       float32
    12-13    toe_height_mm        float32
    14-15    length_mm            float32
    16-17    cycle_time_ms        float32, trigger to result published
    18       glue point count N   uint16, 0..MAX_GLUE_POINTS
    100..    glue points          N x (x, y, z) float32 in the table frame, mm, 6 registers each

Registers that are not listed (7-9, 19-99) are reserved: they read 0 and refuse writes.
docs/modbus.md is the operator-facing version of this table.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from pymodbus.client.mixin import ModbusClientMixin

#: Bumped whenever an address or an encoding changes, so a PLC can refuse a controller it does not know.
MAP_VERSION = 1

#: Fixed upper bound of the glue path so the register map has a fixed size (100 + 6 * 2000 = 12100
#: registers). 2000 points at the ~1 mm spacing a robot dispenser needs cover a 2 m contour, several
#: times the perimeter of the largest sole; a longer path must be resampled before publishing.
MAX_GLUE_POINTS = 2000

#: Registers per glue point: x, y, z as float32.
REGISTERS_PER_POINT = 6


class Register(enum.IntEnum):
    """Start address of each field of the map."""

    HEARTBEAT = 0
    STATUS = 1
    TRIGGER = 2
    RESULT_CYCLE = 3
    ERROR_CODE = 4
    REFUSED_TRIGGERS = 5
    MAP_VERSION = 6
    HEEL_HEIGHT_MM = 10
    TOE_HEIGHT_MM = 12
    LENGTH_MM = 14
    CYCLE_TIME_MS = 16
    GLUE_POINT_COUNT = 18
    GLUE_POINTS = 100


#: First register after the fixed header the PLC normally reads in one request (0..18).
HEADER_SIZE = Register.GLUE_POINT_COUNT + 1

#: Total number of registers: every address below this is readable, none above.
MAP_SIZE = Register.GLUE_POINTS + REGISTERS_PER_POINT * MAX_GLUE_POINTS

#: The only addresses a PLC may write.
PLC_WRITABLE = frozenset({Register.TRIGGER})


class StatusBit(enum.IntFlag):
    """Bits of the status register (1)."""

    READY = 1 << 0  #: not busy, cameras and calibration ok: a trigger now starts a measurement
    BUSY = 1 << 1  #: a trigger was accepted and its result is not published yet
    RESULT_VALID = 1 << 2  #: registers 10.. hold the complete measurement of the result cycle
    ERROR = 1 << 3  #: the result cycle ended with an error; register 4 says which
    CAMERAS_OK = 1 << 4  #: both cameras deliver synchronised frames
    CALIBRATION_OK = 1 << 5  #: a calibration matching the cameras is loaded


class ErrorCode(enum.IntEnum):
    """Value of the error-code register (4). Grouped by tens: cameras, calibration, scene, controller."""

    NONE = 0
    CAMERA_MISSING = 10
    FRAME_TIMEOUT = 11
    CAMERAS_OUT_OF_SYNC = 12
    CALIBRATION_MISSING = 20
    CALIBRATION_MISMATCH = 21
    NO_SOLE = 30
    SOLE_AT_BORDER = 31
    TOO_FEW_POINTS = 32
    MEASUREMENT_INVALID = 33
    COLOURS_TOO_SIMILAR = 34
    ENDS_TOO_CLOSE_TO_CALL = 35
    NO_TABLE = 36
    TABLE_MOVED = 37
    OUTLINE_INCONSISTENT = 38
    GLUE_PATH_INCONSISTENT = 39
    CYCLE_ABORTED = 90
    CYCLE_TIMEOUT = 91
    INTERNAL_ERROR = 99

    @property
    def meaning(self) -> str:
        """What went wrong, in one sentence."""
        return _ERROR_TEXT[self][0]

    @property
    def operator_action(self) -> str:
        """What the line technician should do about it."""
        return _ERROR_TEXT[self][1]


_ERROR_TEXT: dict[ErrorCode, tuple[str, str]] = {
    ErrorCode.NONE: ("No error.", "Nothing."),
    ErrorCode.CAMERA_MISSING: (
        "A camera is not connected or cannot be opened.",
        "Check the USB cables and camera power; the controller reconnects by itself.",
    ),
    ErrorCode.FRAME_TIMEOUT: (
        "A camera delivered no frame in time.",
        "Check the USB cable and hub; if it repeats, replace the cable or camera.",
    ),
    ErrorCode.CAMERAS_OUT_OF_SYNC: (
        "The two frames of the pair were taken too far apart, even after re-grabbing.",
        "Check USB bandwidth (one camera per controller port); re-trigger the cycle.",
    ),
    ErrorCode.CALIBRATION_MISSING: (
        "No stereo calibration is loaded.",
        "Install the calibration file named in the config and restart the service.",
    ),
    ErrorCode.CALIBRATION_MISMATCH: (
        "The calibration does not match the cameras (image size or camera identity).",
        "Re-calibrate the rig, or restore the calibration made for these cameras.",
    ),
    ErrorCode.NO_SOLE: (
        "No sole was found in view.",
        "Check that a sole lies on the table, inside the marked area.",
    ),
    ErrorCode.SOLE_AT_BORDER: (
        "The sole touches the image border, so it cannot be measured whole.",
        "Place the sole inside the marked area and re-trigger.",
    ),
    ErrorCode.TOO_FEW_POINTS: (
        "Too few valid 3D points were reconstructed on the sole.",
        "Check lighting and lens cleanliness; very glossy or dark soles may need more light.",
    ),
    ErrorCode.MEASUREMENT_INVALID: (
        "The measurement is outside plausible limits.",
        "Re-trigger; if it repeats, check the sole and the calibration.",
    ),
    ErrorCode.COLOURS_TOO_SIMILAR: (
        "The sole's colour does not stand out from the table's, so its edge cannot be found.",
        "Use a table cover that contrasts with the sole (dark for light soles, light for dark ones) and re-trigger.",
    ),
    ErrorCode.ENDS_TOO_CLOSE_TO_CALL: (
        "Toe and heel cannot be told apart: both ends of the sole's outline are about equally wide.",
        "Check that one whole sole lies flat on the table with nothing next to it; if it repeats for this sole "
        "model, it cannot be oriented automatically: call the line engineer.",
    ),
    ErrorCode.NO_TABLE: (
        "The table was not found below the sole (view blocked, or the table is not at the configured distance).",
        "Clear the table and the camera view of other objects; if it repeats, check the camera mount and depth range.",
    ),
    ErrorCode.TABLE_MOVED: (
        "The table no longer lies where it was taught: the table, fixture or cameras moved.",
        "Check the fixture and camera mount, clear the table and teach it again (cellctl teach).",
    ),
    ErrorCode.OUTLINE_INCONSISTENT: (
        "The sole's outline disagrees with its depth edge or between the two cameras, so its length is not trusted.",
        "Check that one sole lies flat with nothing touching it and the lenses are clean; re-trigger.",
    ),
    ErrorCode.GLUE_PATH_INCONSISTENT: (
        "The glue path leaves the sole's surface (height jump, out of the sole's height range, or tilted normal).",
        "Re-trigger; if it repeats for this sole, check lighting for glare and call the line engineer.",
    ),
    ErrorCode.CYCLE_ABORTED: (
        "The cycle was abandoned because the service is stopping.",
        "Re-trigger once the heartbeat runs again.",
    ),
    ErrorCode.CYCLE_TIMEOUT: (
        "The cycle took longer than the configured cycle_timeout_s and was abandoned.",
        "Re-trigger; if it repeats, the controller PC is overloaded or a camera hangs: save the service log and "
        "call support.",
    ),
    ErrorCode.INTERNAL_ERROR: (
        "Unexpected fault in the controller software.",
        "Re-trigger; if it repeats, save the service log (journalctl) and call support.",
    ),
}


class WordOrder(enum.Enum):
    """Order of the two 16-bit words of a float32 (bytes inside a word are always big-endian)."""

    HIGH_FIRST = "high_first"  #: "ABCD", Modbus convention, e.g. Siemens, Codesys default
    LOW_FIRST = "low_first"  #: "CDAB", e.g. many Schneider and Allen-Bradley setups

    @property
    def pymodbus_name(self) -> Literal["big", "little"]:
        """The `word_order` argument pymodbus' converters expect."""
        return "big" if self is WordOrder.HIGH_FIRST else "little"


_FLOAT32 = ModbusClientMixin.DATATYPE.FLOAT32
_FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class RegisterMap:
    """Encoding of values into this map's registers for one word order.

    The float conversion itself is pymodbus' (`convert_to_registers`), so the controller encodes
    exactly what a pymodbus client with the same word order decodes.
    """

    word_order: WordOrder = WordOrder.HIGH_FIRST

    def encode_floats(self, values: Sequence[float], what: str = "value") -> list[int]:
        """Registers (2 per value) for float32 values (NaN allowed); refuses finite values too big."""
        checked = [_float32(v, f"{what}[{i}]") for i, v in enumerate(values)]
        if not checked:
            return []
        return ModbusClientMixin.convert_to_registers(checked, _FLOAT32, word_order=self.word_order.pymodbus_name)

    def decode_floats(self, registers: Sequence[int]) -> list[float]:
        """float32 values from registers (2 per value)."""
        if len(registers) % 2:
            raise ValueError(f"float32 needs 2 registers each, got {len(registers)} registers")
        if not registers:
            return []
        decoded = ModbusClientMixin.convert_from_registers(
            list(registers), _FLOAT32, word_order=self.word_order.pymodbus_name
        )
        # pymodbus returns a bare float for a single value; always hand back a list.
        return decoded if isinstance(decoded, list) else [decoded]  # type: ignore[list-item,return-value]

    def encode_points(self, points: ArrayLike) -> list[int]:
        """Registers (6 per point) for an (N, 3) array of x, y, z in mm; N <= MAX_GLUE_POINTS."""
        array = np.asarray(points, dtype=float)
        if array.size == 0:
            return []
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"glue points must be an (N, 3) array of x, y, z, got shape {array.shape}")
        if len(array) > MAX_GLUE_POINTS:
            raise ValueError(
                f"glue path has {len(array)} points but the register map holds at most "
                f"{MAX_GLUE_POINTS}: resample the path before publishing"
            )
        return self.encode_floats(array.ravel().tolist(), what="glue point coordinate")

    def decode_points(self, registers: Sequence[int]) -> np.ndarray:
        """An (N, 3) float32 array of x, y, z from registers (6 per point)."""
        if len(registers) % REGISTERS_PER_POINT:
            raise ValueError(f"glue points need 6 registers each, got {len(registers)} registers")
        return np.asarray(self.decode_floats(registers), dtype=np.float32).reshape(-1, 3)


def _float32(value: float, what: str) -> float:
    number = float(value)
    if math.isfinite(number) and abs(number) > _FLOAT32_MAX:
        raise ValueError(f"{what} = {number!r} is too large for a float32 (max {_FLOAT32_MAX:.3g})")
    return number
