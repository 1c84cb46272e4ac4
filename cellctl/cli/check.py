"""`cellctl check --config CELL.toml`: is this cell ready to run? One line per check, without starting the service.

Checks the config, the calibration file, the state directory, the PLC port (TCP port free, or the serial
device opens), the station's port, the cameras (a synchronised pair), the frames against the calibration
and the rectification on a fresh pair. Exit status 0 when all pass, 1 when any fails. Run it while the
service is stopped (the service owns the cameras and ports).
"""

from __future__ import annotations

import argparse
import socket
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellctl.errors import UserError

if TYPE_CHECKING:
    from cellctl.service.config import CellConfig

#: Residual vertical disparity (RMS) below which the calibration holds (docs/calibration.md, section 3).
RECTIFIED_RMS_LIMIT_PX = 0.3


class CheckFailed(Exception):
    """A check did not pass; the message says what is wrong and what to do."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "check",
        help="check config, cameras, PLC port and calibration without starting the service",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", type=Path, required=True, help="cell config, e.g. /etc/cellctl/cell.toml")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.service.config import CellConfig, ConfigError

    try:
        config = CellConfig.load(args.config)
    except ConfigError as exc:
        _line(False, "config", str(exc))
        return 1
    _line(True, "config", str(config.source))
    context: dict[str, Any] = {}
    checks: list[tuple[str, Callable[[CellConfig, dict[str, Any]], str]]] = [
        ("calibration", _calibration),
        ("taught table", _taught_table),
        ("state dir", _state_dir),
        ("plc", _plc),
        ("station", _station),
        ("cameras", _cameras),
        ("frames", _frames),
        ("rectification", _rectification),
    ]
    passed = True
    for name, check in checks:
        try:
            _line(True, name, check(config, context))
        except CheckFailed as exc:
            _line(False, name, str(exc))
            passed = False
    return 0 if passed else 1


def _line(ok: bool, name: str, text: str) -> None:
    print(f"{'ok  ' if ok else 'FAIL'}  {name:<14} {text}", flush=True)


def _calibration(config: CellConfig, context: dict[str, Any]) -> str:
    from cellctl.vision.calibration import Calibration

    try:
        calib = Calibration.load(config.calibration.path)
    except (OSError, ValueError) as exc:
        raise CheckFailed(f"{exc}") from None
    context["calib"] = calib
    rms = "RMS not recorded" if calib.rms is None else f"RMS {calib.rms:.3f} px"
    width, height = calib.image_size
    return f"{config.calibration.path}: {width}x{height}, {rms}, baseline {calib.baseline_mm:.1f} mm"


def _taught_table(config: CellConfig, context: dict[str, Any]) -> str:
    """The empty fixture taught beside the calibration: loaded, or what the cell does without it."""
    from cellctl.vision.teach import TeachError, load_taught

    if "calib" not in context:
        raise CheckFailed("skipped: needs the calibration")
    try:
        taught = load_taught(config.calibration.path, context["calib"])
    except TeachError as exc:
        raise CheckFailed(f"{exc}") from None
    if taught is not None:
        return "loaded: the sole is found against the taught empty fixture"
    if config.measure.require_taught_table:
        raise CheckFailed("none, and [measure] require_taught_table refuses every cycle: teach it (cellctl teach)")
    return "none: measuring with the colour test (plain one-colour soles on a plain table; cellctl teach for the rest)"


def _state_dir(config: CellConfig, context: dict[str, Any]) -> str:
    state = config.journal.state_dir
    try:
        state.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=state):
            pass
    except OSError as exc:
        raise CheckFailed(
            f"{state} is not writable: {exc.strerror}; fix its owner or point [journal] state_dir elsewhere"
        ) from None
    return f"{state} writable"


def _plc(config: CellConfig, context: dict[str, Any]) -> str:
    plc = config.plc
    if plc.transport == "rtu":
        import serial

        try:
            serial.Serial(plc.serial_port, plc.baudrate, timeout=0.1).close()
        except (serial.SerialException, ValueError) as exc:
            raise CheckFailed(
                f"serial port {plc.serial_port} does not open: {exc}; check the RS-485 adapter and [plc] serial_port"
            ) from None
        return f"serial port {plc.serial_port} opens ({plc.baudrate} baud)"
    _bindable(plc.host, plc.port, "[plc] host/port")
    return f"Modbus TCP {plc.host}:{plc.port} free"


def _station(config: CellConfig, context: dict[str, Any]) -> str:
    station = config.station
    if not station.enabled:
        return "disabled in the config"
    _bindable(station.bind, station.port, "[station] bind/port")
    actions = "actions enabled (token set)" if station.token else "read-only (no token: actions refused)"
    return f"http://{station.bind}:{station.port}/ free; {actions}"


def _bindable(host: str, port: int, keys: str) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            raise CheckFailed(
                f"cannot listen on {host}:{port}: {exc.strerror} (is the service already running? see {keys})"
            ) from None


def _cameras(config: CellConfig, context: dict[str, Any]) -> str:
    from cellctl.cli.cameras import opened_cameras

    calib = context.get("calib")
    if config.cameras.backend == "simulated" and calib is None:
        raise CheckFailed("the simulated cameras render through the calibration, which did not load")
    try:
        with opened_cameras(config, calib, "{}") as source:
            frame = source.grab_pair()
    except UserError as exc:
        raise CheckFailed(str(exc)) from None
    context["frame"] = frame
    height, width = frame.left.shape[:2]
    return f"{config.cameras.backend}: pair of {width}x{height}, skew {frame.skew_s * 1000:.1f} ms"


def _frames(config: CellConfig, context: dict[str, Any]) -> str:
    calib, frame = context.get("calib"), context.get("frame")
    if calib is None or frame is None:
        raise CheckFailed("skipped: needs the calibration and a pair from the cameras")
    for side, image in (("left", frame.left), ("right", frame.right)):
        try:
            calib.check_image(image)
        except ValueError as exc:
            raise CheckFailed(f"{side} frame: {exc}") from None
    return "frame size matches the calibration"


def _rectification(config: CellConfig, context: dict[str, Any]) -> str:
    from cellctl.vision.rectification import vertical_disparity

    calib, frame = context.get("calib"), context.get("frame")
    if calib is None or frame is None:
        raise CheckFailed("skipped: needs the calibration and a pair from the cameras")
    try:
        residual = vertical_disparity(*calib.rectify(frame.left, frame.right))
    except ValueError as exc:
        raise CheckFailed(f"cannot tell on this view: {exc}") from None
    summary = residual.summary().splitlines()[0]
    if residual.rms > RECTIFIED_RMS_LIMIT_PX:
        raise CheckFailed(f"{summary}: above {RECTIFIED_RMS_LIMIT_PX} px, a camera may have moved: calibrate again")
    return summary
