"""The cell's cameras as the service sees them: working or not, the calibrated ones or not.

While the cameras fail, the daemon probes them between cycles (`probe`), so CAMERAS_OK and READY come back
by themselves when a camera is plugged in again; every grab holds `lock`, so the station's live view grabs
between cycles only.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from cellctl.cameras import CameraError, FrameSource, StereoFrame
from cellctl.cameras.averaging import average_frames
from cellctl.cameras.config import AVERAGED_FRAMES
from cellctl.cameras.identity import identity_problem
from cellctl.service.codes import CycleFailed
from cellctl.service.quiet_log import RepeatQuietLog
from cellctl.vision.calibration import Calibration

log = logging.getLogger("cellctl.service.daemon")  # the service's one log, as operators know it

#: Cameras that failed are probed this often between cycles so READY comes back without a trigger.
CAMERA_PROBE_PERIOD_S = 1.0
#: The same camera failure is logged again (at warning level) at most this often.
CAMERA_LOG_REPEAT_S = 60.0


class CameraHealth:
    """Grabs for the cycles, and knows whether the cameras work and are the calibrated ones."""

    def __init__(self, source: FrameSource, calib: Calibration | None, averaged_frames: int = AVERAGED_FRAMES) -> None:
        self.source = source
        self.averaged_frames = averaged_frames  # pairs per cycle, averaged (cellctl.cameras.averaging)
        self.calib = calib
        self.lock = threading.Lock()  # held for every grab
        self.ok = False
        self.identity_problem: str | None = None  # the calibration was made with other cameras
        # The set-up the cell requires beside the calibration and lacks (its taught table): not calibrated either.
        self.setup_problem: str | None = None
        self._log = RepeatQuietLog(log, CAMERA_LOG_REPEAT_S)
        self._last_probe = 0.0

    @property
    def calibration_ok(self) -> bool:
        return self.calib is not None and self.identity_problem is None and self.setup_problem is None

    def probe(self, force: bool = False) -> bool:
        """Open the cameras if they are not known to work (at start, and every few s while failing);
        True when they work again since this call."""
        now = time.monotonic()
        if self.ok or (not force and now - self._last_probe < CAMERA_PROBE_PERIOD_S):
            return False
        self._last_probe = now
        try:
            with self.lock:
                self.source.open()
                frame = self.source.grab_pair()
        except CameraError as exc:
            self._log.warning(str(exc), "cameras not ready: %s", exc)
            return False
        self.ok = True
        self._log.reset()
        log.info("cameras ok")
        # At start and after a reconnect: are these the calibrated cameras (a replug may have swapped them)?
        self.identity_problem = identity_problem(self.calib.cameras if self.calib else None, frame.info)
        if self.identity_problem:
            log.error("calibration does not match the cameras: %s", self.identity_problem)
        return True

    def grab_exposures(self, timings: dict[str, float], not_before: float) -> list[StereoFrame]:
        """The `averaged_frames` pairs a cycle grabs after `not_before` (the trigger), for `averaged`; CycleFailed
        with the camera's code otherwise."""
        return self._grabbing(timings, "grab", lambda: self.source.grab_exposures(self.averaged_frames, not_before))

    def grab_further(self, count: int, timings: dict[str, float]) -> list[StereoFrame]:
        """Up to `count` more pairs of the scene just grabbed (FrameSource.grab_further); CycleFailed otherwise."""
        return self._grabbing(timings, "grab_further", lambda: self.source.grab_further(count))

    @staticmethod
    def averaged(frames: list[StereoFrame], timings: dict[str, float]) -> StereoFrame:
        """The last of `frames` with the mean of those that show the same still scene (cellctl.cameras.averaging)."""
        start = time.perf_counter()
        frame = average_frames(frames)
        timings["average"] = time.perf_counter() - start
        return frame

    def _grabbing(
        self, timings: dict[str, float], step: str, grab: Callable[[], list[StereoFrame]]
    ) -> list[StereoFrame]:
        """`grab()` under the lock, timed as `step`; a camera error marks the cameras failed and is the cycle's."""
        start = time.perf_counter()
        try:
            with self.lock:  # one grab at a time: the station's live view grabs between cycles only
                frames = grab()
        except CameraError as exc:
            self.ok = False
            self._last_probe = time.monotonic()
            raise CycleFailed.of(exc.kind, str(exc)) from exc
        finally:
            timings[step] = time.perf_counter() - start
        self.ok = True
        return frames
