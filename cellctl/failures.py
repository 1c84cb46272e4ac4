"""Why a sole was not measured, as a value a program can act on; the reason text next to it is for people.

Every invalid `Reconstruction` and `SoleMeasurement` carries one `FailureKind`, set where the failure is
detected, and bad input to the reconstruction raises `MeasurementInputError` with its kind. The service
maps kinds to PLC error codes in one table (cellctl.daemon), so rewording a reason never changes what the
robot is told.
"""

from __future__ import annotations

import enum


class FailureKind(enum.Enum):
    """What kind of failure kept a sole from being measured (docs/measurements.md, Validity)."""

    TOO_FEW_POINTS = "too_few_points"  #: the pair gave too few measured pixels to trust (light, focus, depth range)
    NO_TABLE = "no_table"  #: no table plane, or the plane found is not the table
    NO_SOLE = "no_sole"  #: nothing sole-sized above the table
    SOLE_AT_BORDER = "sole_at_border"  #: the sole reaches the edge of what both cameras see
    COLOURS_TOO_SIMILAR = "colours_too_similar"  #: sole and table colours do not separate: no reliable edge
    ENDS_TOO_CLOSE_TO_CALL = "ends_too_close_to_call"  #: toe and heel halves of the footprint too alike
    SURFACE_NOT_MEASURED = "surface_not_measured"  #: no top surface at the heel/toe point or on the glue path
    MEASUREMENT_INVALID = "measurement_invalid"  #: numbers outside plausible limits
    CALIBRATION_MISMATCH = "calibration_mismatch"  #: the images do not match the calibration


class MeasurementInputError(ValueError):
    """Input the reconstruction cannot work on (an error of the call, not a result), with its kind."""

    def __init__(self, kind: FailureKind, message: str) -> None:
        super().__init__(message)
        self.kind = kind
