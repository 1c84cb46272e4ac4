"""The service's edge to the PLC: what the PLC is told for each kind of failure.

Every FailureKind has an entry (tests/service/test_daemon.py checks it); the reason text goes to the journal
and the log, never to the PLC, so rewording a reason cannot change what the robot does.
"""

from __future__ import annotations

from cellctl.errors import FailureKind
from firmware_io.registers import ErrorCode

FAILURE_CODES: dict[FailureKind, ErrorCode] = {
    FailureKind.TOO_FEW_POINTS: ErrorCode.TOO_FEW_POINTS,
    FailureKind.SURFACE_NOT_MEASURED: ErrorCode.TOO_FEW_POINTS,  # same cause and remedy: too little measured
    FailureKind.NO_TABLE: ErrorCode.NO_TABLE,
    FailureKind.NO_SOLE: ErrorCode.NO_SOLE,
    FailureKind.SOLE_AT_BORDER: ErrorCode.SOLE_AT_BORDER,
    FailureKind.COLOURS_TOO_SIMILAR: ErrorCode.COLOURS_TOO_SIMILAR,
    FailureKind.ENDS_TOO_CLOSE_TO_CALL: ErrorCode.ENDS_TOO_CLOSE_TO_CALL,
    FailureKind.MEASUREMENT_INVALID: ErrorCode.MEASUREMENT_INVALID,
    FailureKind.TABLE_MOVED: ErrorCode.TABLE_MOVED,
    FailureKind.OUTLINE_INCONSISTENT: ErrorCode.OUTLINE_INCONSISTENT,
    FailureKind.GLUE_PATH_INCONSISTENT: ErrorCode.GLUE_PATH_INCONSISTENT,
    FailureKind.WALL_TOO_LOW: ErrorCode.WALL_TOO_LOW,
    FailureKind.CALIBRATION_MISMATCH: ErrorCode.CALIBRATION_MISMATCH,
    FailureKind.CALIBRATION_MISSING: ErrorCode.CALIBRATION_MISSING,
    FailureKind.TABLE_NOT_TAUGHT: ErrorCode.TABLE_NOT_TAUGHT,
    FailureKind.CAMERA_MISSING: ErrorCode.CAMERA_MISSING,
    FailureKind.FRAME_TIMEOUT: ErrorCode.FRAME_TIMEOUT,
    FailureKind.CAMERAS_OUT_OF_SYNC: ErrorCode.CAMERAS_OUT_OF_SYNC,
    FailureKind.RECIPE_UNKNOWN: ErrorCode.RECIPE_UNKNOWN,
}


class CycleFailed(Exception):
    """A cycle ends with an error code for the PLC."""

    def __init__(self, code: ErrorCode, reason: str) -> None:
        super().__init__(reason)
        self.code = code

    @classmethod
    def of(cls, failure: FailureKind, reason: str) -> CycleFailed:
        """A failure of a kind, answered with the code the table above gives it."""
        return cls(FAILURE_CODES[failure], reason)
