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

Map version 2 (selected in the config; version 1 stays the default for PLCs already programmed) keeps
every address above and adds recipes, inspection results and the path's frame and normals:

    7        recipe select        uint16, PLC-writable: recipe number the next trigger measures with
    8        result recipe        uint16, recipe the result cycle was measured with
    9        feature fails        uint16 bit field, see FeatureBit (0 = every checked feature in tolerance)
    19       glue frame           uint16, GlueFrame: the frame the glue points are given in
    20-21    nozzle offset mm     float32, distance the points were moved along their normals
    22-23    glue offset mm       float32, inset of the path from the sole's edge
    100..    glue points          N x (x, y, z, nx, ny, nz) float32, 12 registers each

and status bits 6 (IN_TOLERANCE) and 7 (OUT_OF_TOLERANCE).
docs/modbus.md is the operator-facing version of these tables. How values are encoded into registers
(word order, float32, points and normals) is firmware_io.encoding; WordOrder and RegisterMap are re-exported
here, where the rest of the map's vocabulary is.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from firmware_io.encoding import MAX_GLUE_POINTS, REGISTERS_PER_POINT, RegisterMap, WordOrder

#: Bumped whenever an address or an encoding changes, so a PLC can refuse a controller it does not know.
#: The constants below without a version in their name describe this version 1 (MapLayout: either).
MAP_VERSION = 1


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
    # Map version 2 only (reserved, reading 0, in version 1):
    RECIPE_SELECT = 7
    RESULT_RECIPE = 8
    FEATURE_FAILS = 9
    GLUE_FRAME = 19
    NOZZLE_OFFSET_MM = 20
    GLUE_OFFSET_MM = 22


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
    IN_TOLERANCE = 1 << 6  #: map v2: the result cycle's sole is within every tolerance of its recipe
    OUT_OF_TOLERANCE = 1 << 7  #: map v2: a feature is outside its tolerance; register 9 says which


class FeatureBit(enum.IntFlag):
    """Bits of the feature-fails register (9, map v2): a set bit is a feature outside its recipe tolerance."""

    LENGTH = 1 << 0
    HEEL_HEIGHT = 1 << 1
    TOE_HEIGHT = 1 << 2


class GlueFrame(enum.IntEnum):
    """Value of the glue-frame register (19, map v2)."""

    TABLE = 0  #: the cell's table frame (origin under the left camera, z up from the table), as in version 1
    ROBOT_BASE = 1  #: the robot's base frame, through the taught transform (`cellctl teach-robot`)


@dataclass(frozen=True)
class MapLayout:
    """What differs between the map versions: header, point size, writable registers, status bits."""

    version: int
    header_size: int  #: registers 0 .. header_size - 1 are the header a PLC reads in one request
    registers_per_point: int  #: 6 (x, y, z) or 12 (x, y, z, nx, ny, nz)
    plc_writable: frozenset[int]
    status_bits: StatusBit  #: bits this version may set; the rest read 0

    @property
    def size(self) -> int:
        """Total number of registers: every address below this is readable, none above."""
        return Register.GLUE_POINTS + self.registers_per_point * MAX_GLUE_POINTS

    @property
    def has_normals(self) -> bool:
        return self.registers_per_point == 2 * REGISTERS_PER_POINT

    @classmethod
    def of(cls, version: int) -> MapLayout:
        """The layout of a map version; ValueError for a version this controller does not serve."""
        try:
            return _LAYOUTS[version]
        except KeyError:
            raise ValueError(f"register map version {version} unknown: this controller serves 1 and 2") from None


class ErrorCode(enum.IntEnum):
    """Value of the error-code register (4). Grouped by tens: cameras, calibration, scene, controller."""

    NONE = 0
    CAMERA_MISSING = 10
    FRAME_TIMEOUT = 11
    CAMERAS_OUT_OF_SYNC = 12
    CALIBRATION_MISSING = 20
    CALIBRATION_MISMATCH = 21
    TABLE_NOT_TAUGHT = 22
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
    RECIPE_UNKNOWN = 40
    WALL_TOO_LOW = 41
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
    ErrorCode.NONE: (
        "No error.",
        "Nothing.",
    ),
    ErrorCode.CAMERA_MISSING: (
        "A camera is not connected or cannot be opened.",
        "Check the USB cables and camera power; the controller reconnects by itself.",
    ),
    ErrorCode.FRAME_TIMEOUT: (
        "A camera delivered no frame in time.",
        "Check the USB cable and hub; if it repeats, replace the cable or camera.",
    ),
    ErrorCode.CAMERAS_OUT_OF_SYNC: (
        "The two frames were taken too far apart, even after re-grabbing.",
        "Check USB bandwidth (one camera per controller port); re-trigger.",
    ),
    ErrorCode.CALIBRATION_MISSING: (
        "No stereo calibration is loaded.",
        "Install the calibration file named in the config and restart the service.",
    ),
    ErrorCode.CALIBRATION_MISMATCH: (
        "The calibration does not match the cameras (image size or camera identity).",
        "Re-calibrate the rig, or restore the calibration made for these cameras.",
    ),
    ErrorCode.TABLE_NOT_TAUGHT: (
        "The cell measures against a taught empty table and has none it can use.",
        "Clear the fixture and teach the empty table (cellctl teach), then restart the service.",
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
        "Too few valid 3D points were reconstructed on the sole, or ones too imprecise for the glue heights' tolerance.",
        "Check lighting and lens cleanliness; very glossy or dark soles may need more light.",
    ),
    ErrorCode.MEASUREMENT_INVALID: (
        "The measurement is outside plausible limits.",
        "Re-trigger; if it repeats, check the sole and the calibration.",
    ),
    ErrorCode.COLOURS_TOO_SIMILAR: (
        "The sole's colour does not stand out from the table's, so its edge cannot be found.",
        "Use a table cover that contrasts with the sole (dark for light soles, light for dark ones); on a cell with a taught table, clear it and teach it again with the new cover (`cellctl teach`); then re-trigger.",
    ),
    ErrorCode.ENDS_TOO_CLOSE_TO_CALL: (
        "Toe and heel cannot be told apart: both ends of the sole's outline are about equally wide.",
        "Check that one whole sole lies flat on the table with nothing next to it; if it repeats for this sole model, it cannot be oriented automatically: call the line engineer.",
    ),
    ErrorCode.NO_TABLE: (
        "The table was not found below the sole (view blocked, or the table is not at the configured distance).",
        "Clear the table and the camera view of other objects; if it repeats, check the camera mount and depth range"
        " (the reason names the range that fits a table outside it).",
    ),
    ErrorCode.TABLE_MOVED: (
        "The table no longer lies where it was taught: the table, fixture or cameras moved.",
        "Check the fixture and camera mount, clear the table and teach it again (`cellctl teach`).",
    ),
    ErrorCode.OUTLINE_INCONSISTENT: (
        "The sole's outline disagrees with its depth edge or between the two cameras, so its length is not trusted.",
        "Check that one sole lies flat with nothing touching it and the lenses are clean; re-trigger.",
    ),
    ErrorCode.GLUE_PATH_INCONSISTENT: (
        "The glue path leaves the sole's surface (height jump, out of the sole's height range, tilted normal, or a glue line the recipe's wall draft puts on the top edge).",
        "Re-trigger; if it repeats for this sole, check lighting for glare and call the line engineer (a recipe stating a wall draft: raise its [glue] offset_mm as the reason says).",
    ),
    ErrorCode.RECIPE_UNKNOWN: (
        "The recipe number in register 7 names no recipe loaded on this cell (map version 2).",
        "Write the number of an installed recipe before triggering (0 = the cell's default settings), or install the recipe file and restart the service.",
    ),
    ErrorCode.WALL_TOO_LOW: (
        "The sole's wall is too low all round (under 10 mm) for the cameras to tell whether it leans out, so its outline cannot be confirmed as its edge.",
        "Not a fault of the cell: it cannot check a wall this low. If the model's mould shows its wall vertical, declare it in the recipe (`[sole] wall = \"vertical\"`, docs/recipes.md); otherwise glue it from the model's stored path or call the line engineer.",
    ),
    ErrorCode.CYCLE_ABORTED: (
        "The cycle was abandoned because the service is stopping.",
        "Re-trigger once the heartbeat runs again.",
    ),
    ErrorCode.CYCLE_TIMEOUT: (
        "The cycle took longer than the configured `cycle_timeout_s` (default 4 s) and was abandoned; the controller answers this itself, even if it is stuck inside the cycle.",
        "Re-trigger; if it repeats, the controller PC is overloaded or a camera hangs: save the service log and call support.",
    ),
    ErrorCode.INTERNAL_ERROR: (
        "Unexpected fault in the controller software.",
        "Re-trigger; if it repeats, save the service log (`journalctl -u cellctl`) and call support.",
    ),
}


_V1_BITS = StatusBit(0b111111)
_LAYOUTS: dict[int, MapLayout] = {
    1: MapLayout(1, HEADER_SIZE, REGISTERS_PER_POINT, PLC_WRITABLE, _V1_BITS),
    2: MapLayout(
        2,
        Register.GLUE_OFFSET_MM + 2,
        2 * REGISTERS_PER_POINT,
        frozenset({Register.TRIGGER, Register.RECIPE_SELECT}),
        _V1_BITS | StatusBit.IN_TOLERANCE | StatusBit.OUT_OF_TOLERANCE,
    ),
}
#: The newest version: what a new installation should configure.
LATEST_MAP_VERSION = max(_LAYOUTS)

__all__ = [
    "HEADER_SIZE",
    "LATEST_MAP_VERSION",
    "MAP_SIZE",
    "MAP_VERSION",
    "MAX_GLUE_POINTS",
    "PLC_WRITABLE",
    "REGISTERS_PER_POINT",
    "ErrorCode",
    "FeatureBit",
    "GlueFrame",
    "MapLayout",
    "Register",
    "RegisterMap",
    "StatusBit",
    "WordOrder",
]
