"""Which physical camera is behind a device path, and whether it is the one the calibration was made with.

A camera's identity is its /dev/v4l/by-id name (usb-<vendor>_<model>_<serial>-video-index0, made by udev
from the USB descriptors), so it survives replugging and other USB ports. The calibration file records the
identities of its two cameras (`cellctl calibrate --left-camera ... --right-camera ...`); the service compares
them with the cameras it opened, at start and after every reconnect, and names a swap.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

BY_ID = "/dev/v4l/by-id"


def camera_identity(device: str, by_id: str = BY_ID) -> str | None:
    """The by-id name of the camera behind `device` (a by-id path, udev link or /dev/videoN); None if unknown."""
    real = os.path.realpath(device)
    try:
        names = sorted(os.listdir(by_id))
    except OSError:
        return None
    for name in names:
        if name.endswith("-video-index0") and os.path.realpath(os.path.join(by_id, name)) == real:
            return name
    return None


def _same(recorded: str, actual: str) -> bool:
    """A recorded identity matches a full by-id name, a by-id path, or a USB serial inside the name."""
    return os.path.basename(recorded) == actual or f"_{recorded}-" in actual


def identity_problem(recorded: tuple[str, str] | None, info: Mapping[str, Any]) -> str | None:
    """Why the cameras of a frame (info's left_id/right_id) are not the calibrated ones; None if they are."""
    left, right = info.get("left_id"), info.get("right_id")
    if recorded is None or left is None or right is None:
        return None  # nothing recorded, or a backend without identities (simulated, replay)
    if _same(recorded[0], left) and _same(recorded[1], right):
        return None
    if _same(recorded[0], right) and _same(recorded[1], left):
        return (
            f"left and right cameras are swapped: the left device is {left}, calibrated as the right camera; "
            "exchange the cameras' cables or the [cameras] left/right devices in the config"
        )
    return (
        f"the cameras are {left} (left) and {right} (right), but the calibration was made with {recorded[0]} and "
        f"{recorded[1]}: re-calibrate, or connect the calibrated cameras"
    )
