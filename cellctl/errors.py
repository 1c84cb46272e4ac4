"""One failure vocabulary for the whole package: why a cycle could not give a valid result, as a value a
program can act on; the reason text next to it is for people.

Every invalid `Reconstruction` and `SoleMeasurement` carries one `FailureKind`, set where the failure is
detected; bad input to the reconstruction raises `MeasurementInputError` and a camera that cannot deliver a
pair raises a `CameraError`, each with its kind. The service maps kinds to PLC error codes in one table at
its edge (cellctl.service.codes), so rewording a reason never changes what the robot is told, and nothing
below the service knows the PLC's codes.
"""

from __future__ import annotations

import enum


class FailureKind(enum.Enum):
    """What kept a cycle from a valid result (docs/measurements.md, Validity; docs/modbus.md, error codes)."""

    TOO_FEW_POINTS = "too_few_points"  #: the pair gave too few measured pixels to trust (light, focus, depth range)
    NO_TABLE = "no_table"  #: no table plane, or the plane found is not the table
    NO_SOLE = "no_sole"  #: nothing sole-sized above the table
    SOLE_AT_BORDER = "sole_at_border"  #: the sole reaches the edge of what both cameras see
    COLOURS_TOO_SIMILAR = "colours_too_similar"  #: sole and table colours do not separate: no reliable edge
    ENDS_TOO_CLOSE_TO_CALL = "ends_too_close_to_call"  #: toe and heel halves of the footprint too alike
    SURFACE_NOT_MEASURED = "surface_not_measured"  #: no top surface at the heel/toe point or on the glue path
    MEASUREMENT_INVALID = "measurement_invalid"  #: numbers outside plausible limits
    TABLE_MOVED = "table_moved"  #: the table no longer lies where it was taught (table or cameras moved)
    OUTLINE_INCONSISTENT = "outline_inconsistent"  #: the outline disagrees with the depth step or between the cameras
    GLUE_PATH_INCONSISTENT = "glue_path_inconsistent"  #: glue path heights or normals disagree with the sole's surface
    WALL_TOO_LOW = "wall_too_low"  #: the sole's wall is too low all round to confirm its outline as its foot
    CALIBRATION_MISMATCH = "calibration_mismatch"  #: the images do not match the calibration
    CALIBRATION_MISSING = "calibration_missing"  #: no usable calibration is loaded
    TABLE_NOT_TAUGHT = "table_not_taught"  #: the cell requires a taught table and has no usable one
    CAMERA_MISSING = "camera_missing"  #: a camera is not connected or cannot be opened
    FRAME_TIMEOUT = "frame_timeout"  #: a camera delivered no frame in time
    CAMERAS_OUT_OF_SYNC = "cameras_out_of_sync"  #: the two frames were taken too far apart
    RECIPE_UNKNOWN = "recipe_unknown"  #: the PLC selected a recipe number this cell has no recipe for


class MeasurementInputError(ValueError):
    """Input the reconstruction cannot work on (an error of the call, not a result), with its kind."""

    def __init__(self, kind: FailureKind, message: str) -> None:
        super().__init__(message)
        self.kind = kind


class CameraError(Exception):
    """A pair could not be delivered; `kind` says why (the service maps it to what the PLC is told)."""

    kind: FailureKind = FailureKind.CAMERA_MISSING


class CameraMissing(CameraError):
    """A camera is not connected or cannot be opened."""

    kind = FailureKind.CAMERA_MISSING


class FrameTimeout(CameraError):
    """A camera delivered no frame in time."""

    kind = FailureKind.FRAME_TIMEOUT


class OutOfSync(CameraError):
    """The two frames were taken too far apart, even after re-grabbing."""

    kind = FailureKind.CAMERAS_OUT_OF_SYNC


class UserError(Exception):
    """A problem with the user's input: the command line prints it as one clear line and exits with status 2."""
