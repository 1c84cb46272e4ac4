"""Camera identity: by-id names, the comparison with the calibration's record, and the swap (issue 15, finding 14)."""

from __future__ import annotations

import os
from pathlib import Path

from cellctl.cameras.identity import camera_identity, identity_problem

LEFT = "usb-Arducam_OV9281_USB_Camera_SN0001-video-index0"
RIGHT = "usb-Arducam_OV9281_USB_Camera_SN0002-video-index0"


def test_identity_is_the_by_id_name_behind_any_path(tmp_path: Path) -> None:
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    for name, node in ((LEFT, "video0"), (RIGHT, "video2")):
        (tmp_path / node).touch()
        os.symlink(tmp_path / node, by_id / name)
    os.symlink(tmp_path / "video2", tmp_path / "cellctl-cam-right")  # a udev link of deploy/99-cellctl-cameras.rules
    assert camera_identity(str(tmp_path / "video0"), str(by_id)) == LEFT
    assert camera_identity(str(tmp_path / "cellctl-cam-right"), str(by_id)) == RIGHT
    assert camera_identity(str(by_id / LEFT), str(by_id)) == LEFT
    assert camera_identity(str(tmp_path / "nothing"), str(by_id)) is None
    assert camera_identity(str(tmp_path / "video0"), str(tmp_path / "no-by-id")) is None


def test_identity_problem_names_a_swap_and_a_foreign_camera() -> None:
    ok = {"left_id": LEFT, "right_id": RIGHT}
    assert identity_problem((LEFT, RIGHT), ok) is None
    assert identity_problem(("SN0001", "SN0002"), ok) is None  # serials are enough
    assert identity_problem((f"/dev/v4l/by-id/{LEFT}", f"/dev/v4l/by-id/{RIGHT}"), ok) is None
    swapped = identity_problem((RIGHT, LEFT), ok)
    assert swapped is not None and "swapped" in swapped and "exchange" in swapped
    other = identity_problem(("SN0001", "SN0009"), ok)
    assert other is not None and "SN0009" in other and "re-calibrate" in other
    assert identity_problem(None, ok) is None  # an old calibration without identities
    assert identity_problem((LEFT, RIGHT), {"backend": "simulated"}) is None
