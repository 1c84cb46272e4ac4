"""The cameras page's live view and capture: pairs grabbed between cycles, never during one.

Grabs go through the daemon's camera lock and only while the cell is not busy, so a trigger never waits for
more than one preview grab. Frames are grabbed on demand (when a page streams), at most every
PREVIEW_PERIOD_S, and shared by all viewers.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.cameras.base import CameraError, FrameSource, StereoFrame
from cellctl.service.events import CellState
from cellctl.service.station.hub import encode_jpeg, shrink
from cellctl.vision.calibration import Calibration

PREVIEW_PERIOD_S = 0.5  # 2 frames/s: enough to focus by hand, little CPU taken from the next cycle
PREVIEW_WIDTH_PX = 640
HISTOGRAM_BINS = 64


@dataclass(frozen=True)
class Preview:
    """One grabbed pair, or why there is none now."""

    frame: StereoFrame | None
    note: str  # "" when live, else e.g. "paused: cycle 12 running"
    grabbed_at: float


class LiveView:
    """Shared preview grabs for the cameras page."""

    def __init__(
        self,
        source: FrameSource,
        camera_lock: threading.Lock,
        state: Callable[[], CellState],
        calib: Calibration | None,
        depth_range_mm: tuple[float, float],
    ) -> None:
        self.source, self.camera_lock, self.state = source, camera_lock, state
        self.calib, self.depth_range_mm = calib, depth_range_mm
        self._lock = threading.Lock()
        self._last = Preview(None, "no frame yet", 0.0)

    def preview(self) -> Preview:
        """The newest preview, grabbing a new pair if the last is older than PREVIEW_PERIOD_S (blocking)."""
        with self._lock:
            if time.monotonic() - self._last.grabbed_at < PREVIEW_PERIOD_S:
                return self._last
            self._last = self._grab()
            return self._last

    def grab_idle(self) -> StereoFrame:
        """One pair for an action (capture, rectification check); CameraError if busy or failing."""
        state = self.state()
        if state.phase == "busy":
            raise CameraError(f"the cell is measuring cycle {state.cycle}: try again when it is idle")
        if not self.camera_lock.acquire(timeout=5.0):
            raise CameraError("the cameras are in use by a cycle: try again when the cell is idle")
        try:
            return self.source.grab_pair()
        finally:
            self.camera_lock.release()

    def _grab(self) -> Preview:
        now = time.monotonic()
        state = self.state()
        if state.phase == "busy" or not self.camera_lock.acquire(blocking=False):
            return Preview(self._last.frame, f"paused: cycle {state.cycle or ''} running", now)
        try:
            return Preview(self.source.grab_pair(), "", now)
        except CameraError as exc:
            return Preview(None, f"camera error: {exc}", now)
        finally:
            self.camera_lock.release()

    def panel_jpeg(self, side: str) -> bytes:
        """The side's view: image with the measured region, focus score, histogram, as JPEG."""
        preview = self.preview()
        if preview.frame is None:
            return encode_jpeg(_message_panel(preview.note))
        image = preview.frame.left if side == "left" else preview.frame.right
        return encode_jpeg(self.panel(image, side, preview.note))

    def panel(self, image: np.ndarray, side: str, note: str = "") -> np.ndarray:
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        shown = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
        region = None if self.calib is None else measured_region(self.calib, self.depth_range_mm, side)
        if region is not None:
            cv2.polylines(shown, [np.round(region).astype(np.int32)], True, (0, 220, 255), 3, cv2.LINE_AA)
        shown = shrink(shown, PREVIEW_WIDTH_PX)
        text = f"{side}  focus {focus_score(grey):.0f}" + (f"  {note}" if note else "")
        cv2.putText(shown, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(shown, text, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
        return np.vstack([shown, histogram_strip(grey, shown.shape[1])])


def focus_score(grey: np.ndarray) -> float:
    """Variance of the Laplacian: higher is sharper; compare while turning the focus ring, not across scenes."""
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def histogram_strip(grey: np.ndarray, width: int, height: int = 90) -> np.ndarray:
    """The exposure histogram with the share of clipped (0 and 255) pixels; red bars mark clipping."""
    counts = np.bincount((grey // (256 // HISTOGRAM_BINS)).ravel(), minlength=HISTOGRAM_BINS).astype(np.float64)
    strip = np.full((height, width, 3), 24, np.uint8)
    bar_w = width / HISTOGRAM_BINS
    top = max(counts.max(), 1.0)
    for i, count in enumerate(counts):
        h = int(round((height - 24) * count / top))
        colour = (60, 60, 230) if i in (0, HISTOGRAM_BINS - 1) else (200, 200, 200)
        x0, x1 = int(i * bar_w), int((i + 1) * bar_w) - 1
        cv2.rectangle(strip, (x0, height - 2 - h), (x1, height - 2), colour, -1)
    dark, bright = 100.0 * np.mean(grey == 0), 100.0 * np.mean(grey == 255)
    text = f"exposure: mean {grey.mean():.0f}  black {dark:.1f} %  white {bright:.1f} %"
    cv2.putText(strip, text, (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return strip


def measured_region(calib: Calibration, depth_range_mm: tuple[float, float], side: str) -> np.ndarray:
    """Outline (N x 2, raw image pixels) of the part of this camera's view the other camera also sees at the
    nearest working distance: outside it nothing can be matched, so the sole must lie inside."""
    width, height = calib.image_size
    d_max = calib.focal_px * calib.baseline_mm / depth_range_mm[0]
    u0, u1 = (d_max, width - 1.0) if side == "left" else (0.0, width - 1.0 - d_max)
    steps = np.linspace(0.0, 1.0, 24)
    border = np.concatenate(
        [
            np.column_stack([u0 + (u1 - u0) * steps, np.zeros_like(steps)]),
            np.column_stack([np.full_like(steps, u1), (height - 1.0) * steps]),
            np.column_stack([u1 - (u1 - u0) * steps, np.full_like(steps, height - 1.0)]),
            np.column_stack([np.full_like(steps, u0), (height - 1.0) * (1 - steps)]),
        ]
    )
    K, D, R, P = (
        (calib.K1, calib.D1, calib.R1, calib.P1) if side == "left" else (calib.K2, calib.D2, calib.R2, calib.P2)
    )
    rays = np.column_stack(
        [(border[:, 0] - P[0, 2]) / P[0, 0], (border[:, 1] - P[1, 2]) / P[1, 1], np.ones(len(border))]
    )
    raw = rays @ R  # rectified = R @ raw, so raw = R^T @ rectified (row vectors)
    pixels, _ = cv2.projectPoints(raw.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    return pixels.reshape(-1, 2)


def _message_panel(text: str) -> np.ndarray:
    panel = np.full((480, PREVIEW_WIDTH_PX, 3), 40, np.uint8)
    cv2.putText(panel, text[:60], (20, 240), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    return panel
