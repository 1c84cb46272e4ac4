"""Two USB cameras through V4L2, opened by stable device path, paired by kernel timestamp.

Why OpenCV's V4L2 capture rather than linuxpy: OpenCV is already a dependency (no new package on the line
PC), its V4L2 backend splits grab() (dequeue the buffer, keep its kernel timestamp, CAP_PROP_POS_MSEC)
from retrieve() (decode MJPEG/convert YUYV to BGR), which is exactly what pairing needs: both buffers are
dequeued first, back to back, and only the accepted pair is decoded. It also sets size, FOURCC, exposure
and gain through the same properties on every camera. linuxpy would give direct access to every V4L2
control and buffer flag, but adds a dependency for features this cell does not use.

Reconnect: any failure closes both captures; the next grab_pair() reopens them by path. With udev's
stable names (/dev/v4l/by-id/... or the links of deploy/99-cellctl-cameras.rules) a replugged camera
comes back under the same name, so the service recovers without a restart.

Not tested against real devices in CI (none there): tests/test_cameras.py drives this class through a
fake capture object (timestamps, unplug, reopen) and the pairing with fake timestamps.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from cellctl.cameras.base import CameraMissing, FrameTimeout, StereoFrame, consecutive_pairs
from cellctl.cameras.identity import camera_identity
from cellctl.cameras.sync import TimedFrame, grab_synchronised

log = logging.getLogger(__name__)

#: V4L2 FOURCC of each configured pixel format.
FOURCC = {"MJPEG": "MJPG", "YUYV": "YUYV"}

#: V4L2_EXPOSURE_MANUAL as OpenCV's V4L2 backend expects it for CAP_PROP_AUTO_EXPOSURE.
_MANUAL_EXPOSURE = 1


class V4l2Camera:
    """One camera; opened lazily, closed on failure so that the next use reopens it."""

    def __init__(
        self,
        device: str,
        *,
        size: tuple[int, int] | None,
        pixel_format: str = "MJPEG",
        exposure: float | None = None,
        gain: float | None = None,
        timeout_s: float = 1.0,
        open_capture: Callable[..., Any] = cv2.VideoCapture,
    ) -> None:
        self.device = device
        self.size = size
        self.pixel_format = pixel_format
        self.exposure = exposure
        self.gain = gain
        self.timeout_s = timeout_s
        self._open_capture = open_capture
        self._capture: Any = None

    def open(self) -> None:
        if self._capture is not None:
            return
        if not os.path.exists(self.device):
            raise CameraMissing(f"camera {self.device} is not connected (no such device)")
        capture = self._open_capture(self.device, cv2.CAP_V4L2)
        if not capture.isOpened():
            capture.release()
            raise CameraMissing(f"camera {self.device} cannot be opened (in use, or user not in group video?)")
        self._configure(capture)
        self._capture = capture
        log.info("camera %s open", self.device)

    def _configure(self, capture: Any) -> None:
        capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*FOURCC[self.pixel_format]))
        if self.size is not None:
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.size[0])
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.size[1])
        # One queued buffer: a grab returns a fresh frame, not one that waited in the queue.
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        capture.set(cv2.CAP_PROP_READ_TIMEOUT_MSEC, self.timeout_s * 1000.0)
        if self.exposure is not None:
            capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, _MANUAL_EXPOSURE)
            capture.set(cv2.CAP_PROP_EXPOSURE, self.exposure)
        if self.gain is not None:
            capture.set(cv2.CAP_PROP_GAIN, self.gain)
        if self.size is not None:
            actual = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            if actual != tuple(self.size):
                capture.release()
                raise CameraMissing(
                    f"camera {self.device} delivers {actual[0]}x{actual[1]}, not the configured "
                    f"{self.size[0]}x{self.size[1]} {self.pixel_format}: wrong camera or format not supported"
                )

    def grab(self) -> TimedFrame[V4l2Camera]:
        """Dequeue the next buffer (not decoded); its timestamp is the kernel's, in seconds."""
        self.open()
        if not self._capture.grab():
            self.close()
            if not os.path.exists(self.device):
                raise CameraMissing(f"camera {self.device} was unplugged")
            raise FrameTimeout(f"camera {self.device} delivered no frame within {self.timeout_s:g} s")
        return TimedFrame(self._capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, self)

    def retrieve(self) -> np.ndarray:
        """Decode the last grabbed buffer to BGR."""
        ok, image = self._capture.retrieve()
        if not ok or image is None:
            self.close()
            raise FrameTimeout(f"camera {self.device}: the grabbed frame could not be decoded")
        return image

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


class V4l2Cameras:
    """A FrameSource of two V4L2 cameras."""

    def __init__(self, left: V4l2Camera, right: V4l2Camera, *, sync_tolerance_s: float, max_regrabs: int) -> None:
        self.left, self.right = left, right
        self.sync_tolerance_s = sync_tolerance_s
        self.max_regrabs = max_regrabs

    def open(self) -> None:
        try:
            self.left.open()
            self.right.open()
        except CameraMissing:
            self.close()
            raise

    def grab_pair(self, not_before: float | None = None) -> StereoFrame:
        try:
            left, right = grab_synchronised(
                self.left.grab, self.right.grab, self.sync_tolerance_s, self.max_regrabs, not_before
            )
            images = left.payload.retrieve(), right.payload.retrieve()
        except (CameraMissing, FrameTimeout):
            self.close()  # reopen both next time: a replugged camera restarts its stream
            raise
        info: dict[str, str | None] = {"backend": "v4l2", "left": self.left.device, "right": self.right.device}
        # Identities are looked up per pair (a readdir of /dev/v4l/by-id): a replug may change them.
        info |= {"left_id": camera_identity(self.left.device), "right_id": camera_identity(self.right.device)}
        return StereoFrame(images[0], images[1], left.timestamp, right.timestamp, info)

    def grab_exposures(self, count: int, not_before: float | None = None) -> list[StereoFrame]:
        """The next `count` pairs of the streams (the sole lies still: the same scene, new sensor noise)."""
        return consecutive_pairs(self, count, not_before)

    def grab_further(self, count: int) -> list[StereoFrame]:
        """The streams' next `count` pairs: the sole still lies where the last exposures saw it (the averaging
        leaves out any that moved)."""
        return consecutive_pairs(self, count)

    def close(self) -> None:
        self.left.close()
        self.right.close()
