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

    def close(self) -> None: ...
