"""Station actions that touch the cameras: capture a calibration pair, check the rectification on a fresh pair.

Both grab through LiveView.grab_idle (never during a cycle) and return plain data for the page; the token
check is the web layer's job (app.py).
"""

from __future__ import annotations

import threading
from pathlib import Path

from cellctl.calib.board import Checkerboard
from cellctl.service.capture import SavedPair, save_pair
from cellctl.service.station.hub import encode_jpeg, shrink
from cellctl.service.station.live import LiveView
from cellctl.vision.calibration import Calibration
from cellctl.vision.rectification import side_by_side, vertical_disparity


class CameraActions:
    """Capture and rectification check; one at a time (they share the cameras)."""

    def __init__(self, live: LiveView, calib: Calibration | None, capture_dir: Path, board: str | None) -> None:
        self.live, self.calib, self.capture_dir = live, calib, capture_dir
        self.board = None if board is None else Checkerboard.from_spec(board, 1.0)  # square size: unused here
        self._lock = threading.Lock()
        self.last_capture: tuple[SavedPair, bytes] | None = None  # and its preview JPEG
        self.last_rectification: tuple[str, bytes] | None = None  # (summary, side-by-side JPEG)

    def capture(self) -> SavedPair:
        """Save one synchronised pair as the next left_NN.png / right_NN.png, with board detection."""
        with self._lock:
            frame = self.live.grab_idle()
            saved, shown = save_pair(frame, self.capture_dir, self.board)
            self.last_capture = (saved, encode_jpeg(shrink(shown, 960)))
            return saved

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
