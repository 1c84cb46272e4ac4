"""Station actions that touch the cameras: capture a calibration pair, check the rectification on a fresh pair.

Both grab through LiveView.grab_idle (never during a cycle) and return plain data for the page; the token
check is the web layer's job (app.py).
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cellctl.calib.zhang import Checkerboard, find_corners
from cellctl.service.station.hub import encode_jpeg, shrink
from cellctl.service.station.live import LiveView
from cellctl.vision.calibration import Calibration
from cellctl.vision.rectification import side_by_side, vertical_disparity

_PAIR = re.compile(r"left_(\d+)\.png")


@dataclass(frozen=True)
class CaptureResult:
    name: str  # the NN of left_NN.png / right_NN.png
    folder: Path
    board_left: bool | None  # None: no board configured, nothing detected
    board_right: bool | None
    preview_jpeg: bytes

    def to_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "folder": str(self.folder),
            "board_left": self.board_left,
            "board_right": self.board_right,
        }


class CameraActions:
    """Capture and rectification check; one at a time (they share the cameras)."""

    def __init__(self, live: LiveView, calib: Calibration | None, capture_dir: Path, board: str | None) -> None:
        self.live, self.calib, self.capture_dir = live, calib, capture_dir
        self.board = None if board is None else Checkerboard.from_spec(board, 1.0)  # square size: unused here
        self._lock = threading.Lock()
        self.last_capture: CaptureResult | None = None
        self.last_rectification: tuple[str, bytes] | None = None  # (summary, side-by-side JPEG)

    def capture(self) -> CaptureResult:
        """Save one synchronised pair as the next left_NN.png / right_NN.png, with board detection."""
        with self._lock:
            frame = self.live.grab_idle()
            self.capture_dir.mkdir(parents=True, exist_ok=True)
            name = f"{next_index(self.capture_dir):02d}"
            for side, image in (("left", frame.left), ("right", frame.right)):
                path = self.capture_dir / f"{side}_{name}.png"
                if not cv2.imwrite(str(path), image):
                    raise OSError(f"cannot write {path}: check the state directory is writable")
            found = [self._detect(image) for image in (frame.left, frame.right)]
            previews = [shrink(image, 480) for image, _ in found]
            result = CaptureResult(name, self.capture_dir, found[0][1], found[1][1], encode_jpeg(np.hstack(previews)))
            self.last_capture = result
            return result

    def _detect(self, image: np.ndarray) -> tuple[np.ndarray, bool | None]:
        if self.board is None:
            return image, None
        corners = find_corners(image, self.board)
        shown = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if corners is not None:
            cv2.drawChessboardCorners(
                shown, self.board.pattern_size, corners.reshape(-1, 1, 2).astype(np.float32), True
            )
        return shown, corners is not None

    def rectification_check(self) -> str:
        """Rectify a fresh pair with the loaded calibration and measure the vertical disparity of matches."""
        if self.calib is None:
            raise ValueError("no calibration is loaded: see the service log for why")
        with self._lock:
            frame = self.live.grab_idle()
            left, right = self.calib.rectify(frame.left, frame.right)
            summary = vertical_disparity(left, right).summary()
            self.last_rectification = (summary, encode_jpeg(shrink(side_by_side(left, right), 1600)))
            return summary


def next_index(folder: Path) -> int:
    """One past the highest NN of left_NN.png in the folder (0 when empty)."""
    numbers = [int(m.group(1)) for p in folder.iterdir() if (m := _PAIR.fullmatch(p.name))]
    return max(numbers, default=-1) + 1
