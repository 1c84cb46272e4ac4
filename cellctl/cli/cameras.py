"""The configured cameras for a command that grabs pairs itself (capture, check, teach-robot --locate-live).

    with opened_cameras(config, calib, "cameras: {}") as source:
        frame = source.grab_pair()

A camera failure becomes one UserError line (the command's own words around the camera's); the cameras
are closed whatever happens, so the service can have them again.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from cellctl.errors import UserError

if TYPE_CHECKING:
    from cellctl.cameras import FrameSource
    from cellctl.service.config import CellConfig
    from cellctl.vision.calibration import Calibration


@contextmanager
def opened_cameras(config: CellConfig, calib: Calibration | None, problem: str) -> Iterator[FrameSource]:
    """The [cameras] of `config`, opened; `problem` formats a CameraError's text into the UserError line.
    `calib` is needed by the simulated cameras only (they render through it)."""
    from cellctl.cameras import CameraError, open_frame_source  # OpenCV behind it: not for --help

    try:
        source = open_frame_source(config.cameras, calib)
    except ValueError as exc:
        raise UserError(f"{config.source}: [cameras] {exc}") from None
    try:
        source.open()
        yield source
    except CameraError as exc:
        raise UserError(problem.format(exc)) from None
    finally:
        source.close()
