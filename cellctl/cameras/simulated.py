"""Simulated cameras: sole scenes rendered through the rig of a calibration, with injectable faults.

Each grab_pair() shows the next scene of `seeds` in turn (SoleScene.random(seed)), rendered once per seed
and cached, so cycles after the first round cost no rendering. The two cameras run free at FRAME_PERIOD_S
like real USB cameras; `skew_s` offsets the right camera's frame clock, and the pairs go through the same
timestamp pairing as the V4L2 backend (cellctl.cameras.sync), so a skew near half a frame period yields
out-of-sync pairs that re-grabbing cannot fix. Faults for tests and drills: unplug()/replug(),
drop_frames(n).
"""

from __future__ import annotations

import threading
import time

from cellctl.cameras.base import CameraMissing, FrameTimeout, StereoFrame
from cellctl.cameras.sync import TimedFrame, grab_synchronised
from cellctl.sim.render import RenderedPair
from cellctl.sim.scene import SoleScene
from cellctl.vision.calibration import Calibration

FRAME_PERIOD_S = 1.0 / 30.0


class SimulatedCameras:
    """A FrameSource rendering simulated sole scenes; `info` of each frame holds the seed and the truth."""

    def __init__(
        self,
        calib: Calibration,
        seeds: tuple[int, ...] = (1,),
        color: str = "white",
        *,
        skew_s: float = 0.0,
        sync_tolerance_s: float = 0.008,
        max_regrabs: int = 4,
    ) -> None:
        if not seeds:
            raise ValueError("simulated cameras need at least one scene seed")
        self.calib = calib
        self.seeds = tuple(seeds)
        self.color = color
        self.skew_s = skew_s
        self.sync_tolerance_s = sync_tolerance_s
        self.max_regrabs = max_regrabs
        self._next = 0
        self._cache: dict[int, tuple[RenderedPair, dict[str, object]]] = {}
        self._lock = threading.Lock()
        self._unplugged: str | None = None
        self._frames_to_drop = 0

    # ---- fault injection (thread-safe: tests call these while the service runs) ----------------

    def unplug(self, side: str = "left") -> None:
        """Make the `side` camera disappear until replug()."""
        with self._lock:
            self._unplugged = side

    def replug(self) -> None:
        with self._lock:
            self._unplugged = None

    def drop_frames(self, count: int) -> None:
        """The next `count` frame grabs deliver nothing (each grab_pair then fails with FrameTimeout)."""
        with self._lock:
            self._frames_to_drop = count

    # ---- FrameSource ---------------------------------------------------------------------------

    def scene_for(self, seed: int) -> tuple[RenderedPair, dict[str, object]]:
        """The rendered pair and truth of one seed (rendered on first use, then cached)."""
        if seed not in self._cache:
            scene = SoleScene.random(seed=seed, color=self.color, calib=self.calib)
            truth = scene.truth()
            info = {
                "backend": "simulated",
                "seed": seed,
                "color": self.color,
                "truth": {k: truth[k] for k in ("length_mm", "heel_height_mm", "toe_height_mm")},
            }
            self._cache[seed] = (scene.render(), info)
        return self._cache[seed]

    def open(self) -> None:
        """Render every scene now, so that no cycle waits for the renderer (seconds per 1280x1024 pair)."""
        self._check_plugged()
        for seed in self.seeds:
            self.scene_for(seed)

    def grab_pair(self, not_before: float | None = None) -> StereoFrame:
        self._check_plugged()
        seed = self.seeds[self._next % len(self.seeds)]
        self._next += 1
        start = time.monotonic()
        frame_number = {"left": 0, "right": 0}

        def grab(side: str) -> TimedFrame[None]:
            self._take_frame(side)
            offset = self.skew_s if side == "right" else 0.0
            timestamp = start + offset + frame_number[side] * FRAME_PERIOD_S
            frame_number[side] += 1
            return TimedFrame(timestamp, None)

        left, right = grab_synchronised(
            lambda: grab("left"), lambda: grab("right"), self.sync_tolerance_s, self.max_regrabs, not_before
        )
        pair, info = self.scene_for(seed)
        return StereoFrame(pair.left, pair.right, left.timestamp, right.timestamp, dict(info))

    def close(self) -> None:
        self._cache.clear()

    def _check_plugged(self) -> None:
        with self._lock:
            unplugged = self._unplugged
        if unplugged is not None:
            raise CameraMissing(f"{unplugged} camera (simulated) is unplugged")

    def _take_frame(self, side: str) -> None:
        with self._lock:
            if self._frames_to_drop > 0:
                self._frames_to_drop -= 1
                raise FrameTimeout(f"{side} camera (simulated) delivered no frame: frame dropped")
