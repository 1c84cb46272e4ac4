"""Simulated cameras: sole scenes rendered through the rig of a calibration, with injectable faults.

Each grab_pair() shows the next scene of `seeds` in turn (SoleScene.random(seed)), rendered once per seed
and cached, so cycles after the first round cost no rendering. grab_exposures(n) shows the next scene in up to
`exposures` exposures, each with its own sensor noise (cellctl.sim.render_cache.render_exposures), as a still
sole looks to real cameras frame after frame; grab_further(n) that scene's next ones. The two cameras run
free at FRAME_PERIOD_S like real USB cameras; `skew_s` offsets the right camera's frame clock, and the pairs go
through the same timestamp pairing as the V4L2 backend (cellctl.cameras.sync), so a skew near half a frame period
yields out-of-sync pairs that re-grabbing cannot fix. Faults for tests and drills: unplug()/replug(),
drop_frames(n).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from cellctl.cameras.base import CameraMissing, FrameTimeout, StereoFrame
from cellctl.cameras.sync import TimedFrame, grab_synchronised
from cellctl.sim.render import RenderedPair
from cellctl.sim.render_cache import exposure_shots, render_exposures
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
        exposures: int = 1,
    ) -> None:
        if not seeds:
            raise ValueError("simulated cameras need at least one scene seed")
        if exposures < 1:
            raise ValueError(f"simulated cameras render one or more exposures per scene, got {exposures}")
        self.calib = calib
        self.seeds = tuple(seeds)
        self.color = color
        self.skew_s = skew_s
        self.sync_tolerance_s = sync_tolerance_s
        self.max_regrabs = max_regrabs
        self._next = 0
        self.exposures = exposures
        self._cache: dict[int, tuple[RenderedPair, dict[str, object]]] = {}
        self._further: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}  # exposures 2... (images only)
        self._lock = threading.Lock()
        self._unplugged: str | None = None
        self._frames_to_drop = 0
        self._shown: tuple[int, int] | None = None  # the last grab's scene seed and how many exposures it showed

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
        """The rendered pair (its first exposure) and truth of one seed (rendered on first use, then cached)."""
        if seed not in self._cache:
            scene = SoleScene.random(seed=seed, color=self.color, calib=self.calib)
            truth = scene.truth()
            info = {
                "backend": "simulated",
                "seed": seed,
                "color": self.color,
                "truth": {k: truth[k] for k in ("length_mm", "heel_height_mm", "toe_height_mm")},
            }
            pairs = render_exposures(scene, exposure_shots(self.exposures))
            self._cache[seed] = (pairs[0], info)
            self._further[seed] = [(p.left, p.right) for p in pairs[1:]]
        return self._cache[seed]

    def open(self) -> None:
        """Render every scene now, so that no cycle waits for the renderer (seconds per 1280x1024 pair)."""
        self._check_plugged()
        for seed in self.seeds:
            self.scene_for(seed)

    def grab_pair(self, not_before: float | None = None) -> StereoFrame:
        return self.grab_exposures(1, not_before)[0]

    def grab_exposures(self, count: int, not_before: float | None = None) -> list[StereoFrame]:
        """The next scene in up to `count` exposures (at most `exposures`; at least one)."""
        self._check_plugged()
        seed = self.seeds[self._next % len(self.seeds)]
        self._next += 1
        self._shown = (seed, max(1, min(count, self.exposures)))
        return self._frames(seed, 0, self._shown[1], not_before)

    def grab_further(self, count: int) -> list[StereoFrame]:
        """Up to `count` further exposures of the scene the last grab showed, as many as it has rendered beyond
        those shown (`exposures` in all)."""
        self._check_plugged()
        if self._shown is None:
            return []
        seed, shown = self._shown
        further = max(0, min(count, self.exposures - shown))
        self._shown = (seed, shown + further)
        return self._frames(seed, shown, further, None)

    def _frames(self, seed: int, first: int, count: int, not_before: float | None) -> list[StereoFrame]:
        """Exposures first .. first + count - 1 of the seed's scene, through the cameras' free-running clocks."""
        start = time.monotonic()
        frame_number = {"left": 0, "right": 0}

        def grab(side: str) -> TimedFrame[None]:
            self._take_frame(side)
            offset = self.skew_s if side == "right" else 0.0
            timestamp = start + offset + frame_number[side] * FRAME_PERIOD_S
            frame_number[side] += 1
            return TimedFrame(timestamp, None)

        pair, info = self.scene_for(seed)
        images = [(pair.left, pair.right), *self._further[seed]][first : first + count]
        frames = []
        for left_image, right_image in images:
            left, right = grab_synchronised(
                lambda: grab("left"), lambda: grab("right"), self.sync_tolerance_s, self.max_regrabs, not_before
            )
            frames.append(StereoFrame(left_image, right_image, left.timestamp, right.timestamp, dict(info)))
        return frames

    def close(self) -> None:
        self._cache.clear()
        self._further.clear()

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
