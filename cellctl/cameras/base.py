"""What every camera backend delivers: a stereo pair taken at (nearly) the same moment, or a CameraError."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from cellctl.errors import CameraError, CameraMissing, FrameTimeout, OutOfSync

__all__ = ["CameraError", "CameraMissing", "FrameSource", "FrameTimeout", "OutOfSync", "StereoFrame"]


@dataclass
class StereoFrame:
    """One synchronised pair: BGR uint8 images and their capture times (seconds, one clock per source)."""

    left: np.ndarray
    right: np.ndarray
    t_left: float
    t_right: float
    # Where the pair came from, journaled with the cycle: e.g. the simulated scene seed, the replay file.
    info: dict[str, Any] = field(default_factory=dict)
    # The mean of several exposures of this same still view (cellctl.cameras.averaging), for the sole's surface
    # fits; None for a single exposure.
    averaged: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def skew_s(self) -> float:
        return abs(self.t_left - self.t_right)


class FrameSource(Protocol):
    """A pair of cameras. grab_pair() either returns a synchronised pair or raises a CameraError;
    after an error the next grab_pair() tries again (reconnecting if needed), so the service
    recovers without a restart."""

    def open(self) -> None:
        """Connect and prepare (called at service start); raises a CameraError if not possible now."""

    def grab_pair(self, not_before: float | None = None) -> StereoFrame:
        """A synchronised pair; with not_before (time.monotonic()), both frames were taken at or after it."""
        ...

    def grab_exposures(self, count: int, not_before: float | None = None) -> list[StereoFrame]:
        """Up to `count` (at least one) consecutive synchronised pairs of the same scene, as `grab_pair` takes
        them, for a cycle to average (cellctl.cameras.averaging); a source of stored pairs gives one."""
        ...

    def grab_further(self, count: int) -> list[StereoFrame]:
        """Up to `count` more pairs of the scene the last `grab_exposures` showed, for a cycle that measures it
        once more on more exposures (cellctl.service.measuring); none from a source that has no more of it (a
        stored pair)."""
        ...

    def close(self) -> None: ...


def consecutive_pairs(source: FrameSource, count: int, not_before: float | None = None) -> list[StereoFrame]:
    """`count` (at least one) pairs grabbed one after the other from a live source (`FrameSource.grab_exposures`)."""
    return [source.grab_pair(not_before) for _ in range(max(count, 1))]
