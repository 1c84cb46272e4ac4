"""What each PLC error code means and what the operator should do, in words for the station's pages.

The same table as docs/modbus.md "Error codes" (tests/service/test_station_pages.py checks they agree),
kept here because the docs are not installed with the package.
"""

from __future__ import annotations

from firmware_io.registers import ErrorCode

OPERATOR_TEXT: dict[ErrorCode, tuple[str, str]] = {
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
        "Check that one whole sole lies flat on the table with nothing next to it; if it repeats for this sole model, it cannot be oriented automatically: call the line engineer.",
    ),
    ErrorCode.NO_TABLE: (
        "The table was not found below the sole (view blocked, or the table is not at the configured distance).",
        "Clear the table and the camera view of other objects; if it repeats, check the camera mount and depth range.",
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
        "The glue path leaves the sole's surface (height jump, out of the sole's height range, or tilted normal).",
        "Re-trigger; if it repeats for this sole, check lighting for glare and call the line engineer.",
    ),
    ErrorCode.RECIPE_UNKNOWN: (
        "The recipe number in register 7 names no recipe loaded on this cell (map version 2).",
        "Write the number of an installed recipe before triggering (0 = the cell's default settings), "
        "or install the recipe file and restart the service.",
    ),
    ErrorCode.CYCLE_ABORTED: (
        "The cycle was abandoned because the service is stopping.",
        "Re-trigger once the heartbeat runs again.",
    ),
    ErrorCode.CYCLE_TIMEOUT: (
        "The cycle took longer than the configured `cycle_timeout_s` (default 4 s) and was abandoned; the "
        "controller answers this itself, even if it is stuck inside the cycle.",
        "Re-trigger; if it repeats, the controller PC is overloaded or a camera hangs: save the service log and "
        "call support.",
    ),
    ErrorCode.INTERNAL_ERROR: (
        "Unexpected fault in the controller software.",
        "Re-trigger; if it repeats, save the service log (`journalctl -u cellctl`) and call support.",
    ),
}


def describe_code(code: int) -> tuple[str, str, str]:
    """(name, meaning, operator action) of an error code; an unknown code still gets a line."""
    try:
        known = ErrorCode(code)
    except ValueError:
        return str(code), f"Unknown error code {code}.", "Save the service log and call support."
    meaning, action = OPERATOR_TEXT.get(known, ("", ""))
    return known.name, meaning, action
