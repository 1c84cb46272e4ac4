"""The station's view of the daemon: its latest state and last cycle, with version numbers for live pages.

The daemon's thread publishes into the hub (a subscriber of Daemon.events); the web thread reads it. The
overlay picture of the last cycle is drawn only when a page asks for it, never in the cycle.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from cellctl.service.events import CellEvent, CellState, CycleDone
from cellctl.vision.calibration import Calibration
from cellctl.vision.overlay import draw_overlay, draw_refused

OVERLAY_WIDTH_PX = 1600  # wide enough to read the caption, small enough to send every cycle


class StationHub:
    """Latest state and last cycle; `version` grows with every event (the pages poll it through SSE)."""

    def __init__(self, calib: Calibration | None) -> None:
        self.calib = calib
        self.state = CellState()
        self.last: CycleDone | None = None
        self.state_version = 0
        self.cycle_version = 0
        self._lock = threading.Lock()
        self._overlay: tuple[int, bytes] | None = None  # (cycle_version, PNG)

    def on_event(self, event: CellEvent) -> None:
        """Subscriber for Daemon.events."""
        with self._lock:
            if isinstance(event, CellState):
                self.state = event
                self.state_version += 1
            elif isinstance(event, CycleDone):
                self.last = event
                self.cycle_version += 1

    def last_overlay_png(self) -> bytes | None:
        """The last cycle's picture (the `cellctl measure --png` renderer), PNG, drawn once per cycle."""
        with self._lock:
            last, version, cached = self.last, self.cycle_version, self._overlay
        if last is None or last.frame is None:
            return None
        if cached is not None and cached[0] == version:
            return cached[1]
        if last.measured is not None and self.calib is not None:
            m = last.measured
            picture = draw_overlay(last.frame.left, self.calib, m.reconstruction, m.measurement)
        else:
            r = last.record
            picture = draw_refused(last.frame.left, f"cycle {r.cycle}: error {r.error_code}: {r.reason}")
        png = encode_png(shrink(picture, OVERLAY_WIDTH_PX))
        with self._lock:
            self._overlay = (version, png)
        return png


def shrink(image: np.ndarray, width: int) -> np.ndarray:
    if image.shape[1] <= width:
        return image
    height = int(round(image.shape[0] * width / image.shape[1]))
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def encode_png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError("cannot encode the picture as PNG")
    return data.tobytes()


def encode_jpeg(image: np.ndarray, quality: int = 80) -> bytes:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("cannot encode the picture as JPEG")
    return data.tobytes()
